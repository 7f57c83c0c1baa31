"""The fourth hostile survey's minor findings on `mjtrial verify` and `mjtrial diff` (issue 34
case 14). Each test failed before its fix."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
import rerun as rr

from mjtrial.cli import main
from mjtrial.diff.gate import render
from mjtrial.diff.made import how_made
from mjtrial.diff.source import Run
from mjtrial.files.layout import Layout

pytestmark = pytest.mark.end_to_end

LAYOUT = Layout.of("research_mode")


def _run(capsys, *args) -> tuple[int, str, str]:
    code = main([*map(str, args)])
    out = capsys.readouterr()
    return code, out.out, out.err


def test_strict_with_no_resimulation_is_refused_not_verified(built, capsys):
    """`--strict --resimulate 0` said "verified" having re-simulated nothing."""
    code, out, err = _run(
        capsys, "verify", built / LAYOUT.root, "--repo-root", built, "--strict", "--resimulate", 0
    )
    assert (code, out) == (2, "")
    assert err.splitlines() == [
        "mjtrial verify: --strict with --resimulate 0: a strict check re-simulates episodes; "
        "give --resimulate K > 0 (or `all`), or leave it out"
    ]
    code, out, _ = _run(capsys, "verify", built / LAYOUT.root, "--repo-root", built, "--strict")
    assert code == 0 and "verified: " in out


def _sealed(folder: Path) -> Path:
    """A run's folder, as far as its seal says."""
    folder.mkdir()
    (folder / "seal.json").write_text(json.dumps({"outputs": {"results/x/states.parquet": "0"}}))
    return folder


def test_a_negative_tolerance_names_the_tolerance(tmp_path, capsys):
    """The error named the level (`level 0.05: expected in (0, 1); tolerance -1.0: >= 0`)."""
    sealed = _sealed(tmp_path / "sealed")
    code, _, err = _run(capsys, "diff", sealed, sealed, "--tolerance", -1, "--out", tmp_path / "d")
    assert code == 2
    assert err.splitlines() == ["mjtrial diff: tolerance -1.0: expected >= 0"]


def test_diff_out_through_a_symlink_never_writes_into_a_run(tmp_path, capsys):
    sealed = _sealed(tmp_path / "sealed")
    link = tmp_path / "out"
    link.symlink_to(sealed, target_is_directory=True)
    code, _, err = _run(capsys, "diff", sealed, sealed, "--out", link / "diff")
    assert code == 2
    assert "never writes into a run" in err and err.count("\n") == 1, err
    assert not (sealed / "diff").exists()


def _diff(made: dict, flipped: list) -> dict:
    outputs = {k: [] for k in ("only_a", "only_b", "same", "same_content", "differ")}
    rate = {"n": 4, "successes": 1, "rate": 0.25}
    paired = {"n": 4, "a": rate, "b": rate, "only_a": 0, "only_b": len(flipped), "p_value": 0.5}
    return {
        "runs": {"a": "a", "b": "b"},
        "made": made,
        "outputs": {**outputs, "recordings": []},
        "conditions": {"fast": {"a": rate, "b": rate, "paired": paired, "flipped": flipped}},
        "effects": {},
        "tolerance": 1e-6,
        "level": 0.05,
        "recording": None,
    }


def test_the_commit_is_said_once_and_names_are_shown_unescaped():
    """"commit: commit: ..." and `robot0\\:shoulder_lift_link` (Rerun's escaping) in the text."""
    name = "robot0:shoulder_lift_link"
    quantity = f"world/{rr.escape_entity_path_part(name)}/position"
    assert "\\:" in quantity
    flip = {
        "state_id": 3,
        "success": [False, True],
        "failure_category": ["slipped", None],
        "divergence": {"time": 0.05, "step": [24, 24], "quantity": quantity, "difference": 1e-3},
    }
    made = {"commit": [{"key": "commit", "a": "a" * 40, "b": "b" * 40}]}
    lines = render(_diff(made, [flip])).splitlines()
    assert f"  commit: {'a' * 40} -> {'b' * 40}" in lines
    (episode,) = [line for line in lines if line.startswith("  fast state 3:")]
    assert f"(world/{name}/position by 0.001)" in episode and "\\" not in episode


def _manifest_run(folder: Path, conditions: dict) -> Run:
    folder.mkdir()
    manifest = {"rerun": {"config": {"conditions": conditions}}}
    (folder / "manifest.json").write_text(json.dumps(manifest))
    return Run(label=folder.name, root=folder, outputs={})


def test_a_condition_given_settings_is_not_said_to_be_absent(tmp_path):
    """`conditions.nominal: {} -> (absent)` for a condition that is in both runs."""
    a = _manifest_run(tmp_path / "a", {"nominal": {}, "slow": {"lift_time": 1.5}})
    b = _manifest_run(tmp_path / "b", {"nominal": {"latency": 0.02}, "slow": {"lift_time": 1.5}})
    assert how_made(a, b)["config"] == [
        {"key": "conditions.nominal.latency", "a": None, "b": 0.02}
    ]
    assert how_made(b, a)["config"] == [
        {"key": "conditions.nominal.latency", "a": 0.02, "b": None}
    ]
    # a condition gone is still said to be
    c = _manifest_run(tmp_path / "c", {"slow": {"lift_time": 1.5}})
    assert how_made(a, c)["config"] == [{"key": "conditions.nominal", "a": {}, "b": None}]
