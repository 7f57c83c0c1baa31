"""The fourth hostile survey, `verify --strict` on ordinary work: each warning names its remedy
in one line, and a platform difference whose re-simulations all agree is a note, not a doubt.
(A stale pilot is a note: tests/test_pilot.py.) Each test failed before its fix."""

from __future__ import annotations

import pytest
from test_verify import PREFIX, VERSIONS, chain, check

from mjtrial import provenance
from mjtrial.cli import main
from mjtrial.files.layout import Layout
from mjtrial.verify import verify_results

pytestmark = pytest.mark.end_to_end

LAYOUT = Layout.of("research_mode")


def test_each_disagreement_of_the_stamps_names_the_command_that_rebuilds_them():
    stamps, shas = chain()
    stamps[f"{PREFIX}a.json"]["git"] = {"available": True, "commit": "c2", "diff_sha256": "d"}
    stamps[f"{PREFIX}r.parquet"]["versions"] = {**VERSIONS, "mujoco": "3.13.0"}
    stamps[f"{PREFIX}s.parquet"]["platform"] = {"cpu_model": "CPU C", "cpu_flags_fp": ["sse"]}
    report = check(stamps, shas)
    for start in ("stamps disagree on the git state", "stamps disagree on mujoco", "stamps were"):
        (warning,) = [w for w in report.warnings if w.startswith(start)]
        assert "`snakemake -c2 --forceall`" in warning and "rebuilds" in warning, warning
        assert "\n" not in warning


def test_another_cpu_whose_re_simulations_agree_is_a_note(built, monkeypatch, capsys):
    """Survey case 11: on another CPU model whose re-simulated episodes all matched bit for bit,
    `--strict` failed on "platform differs"."""
    here = provenance.platform_fingerprint()
    other = {**here, "cpu_model": "Another CPU 9000"}
    monkeypatch.setattr(provenance, "platform_fingerprint", lambda: other)
    report = verify_results(
        built / LAYOUT.root,
        config_path=built / "config" / "config.yaml",
        repo_root=built,
        resimulate=2,
    )
    assert report.ok and report.complete, report.format()
    (note,) = [n for n in report.notes if n.startswith("platform differs from this machine")]
    assert "Another CPU 9000" in note and "re-simulated here all agree bit for bit" in note
    monkeypatch.chdir(built)
    assert main(["verify", "--strict", "--resimulate", "2"]) == 0, capsys.readouterr().err
    # With nothing re-simulated, nothing settles it: a warning, and --strict fails.
    report = verify_results(
        built / LAYOUT.root,
        config_path=built / "config" / "config.yaml",
        repo_root=built,
        resimulate=0,
    )
    assert any(w.startswith("platform differs") for w in report.warnings), report.format()
    assert not report.complete
