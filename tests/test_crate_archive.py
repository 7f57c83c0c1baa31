"""`mjtrial crate --zip`: the results, the crate and the workflow's sources in one archive that
is a crate too; unpacked in an empty folder elsewhere it verifies and, once installed there,
Snakemake has nothing to do. A folder whose files no longer match its crate is not archived."""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
import sysconfig
import zipfile
from pathlib import Path

import pytest
from rocrate.rocrate import ROCrate

from mjtrial import cli
from mjtrial.crate import validation
from mjtrial.files.layout import Layout

pytestmark = pytest.mark.end_to_end

LAYOUT = Layout.of("research_mode")


@pytest.fixture(scope="module")
def archive(built, tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("archive") / "run.zip"
    code = cli.main(
        ["crate", str(built / LAYOUT.root), "--zip", str(out), "--repo-root", str(built)]
    )
    assert code == 0
    return out


def test_the_archive_holds_the_results_their_crate_and_the_sources(built, archive):
    with zipfile.ZipFile(archive) as z:
        names = set(z.namelist())
        top = json.loads(z.read("ro-crate-metadata.json"))
    for source in ("Snakefile", "pyproject.toml", "README.md", "src/mjtrial/cli/__init__.py"):
        assert source in names
    assert "workflow/rules/crate.smk" in names and "tasks/gantry_lift/task.py" in names
    sealed = json.loads((built / LAYOUT.seal).read_text())["outputs"]
    run = [built / p for p in sealed] + [built / LAYOUT.seal, built / LAYOUT.crate]
    run += [p for p in (built / LAYOUT.source).rglob("*") if p.is_file()]
    for file in run:
        files = [q for q in file.rglob("*") if q.is_file()] if file.is_dir() else [file]
        for f in files:
            assert f.relative_to(built).as_posix() in names, f
    # The jobs' logs are not the run's results (no seal lists them): left out.
    assert list((built / LAYOUT.logs_dir).glob("*.log"))
    assert not [n for n in names if n.startswith(f"{LAYOUT.logs_dir.as_posix()}/")]
    entities = {e["@id"]: e for e in top["@graph"]}
    assert entities["./"]["mainEntity"] == {"@id": "Snakefile"}
    assert (
        entities["results/research_mode/states.parquet"]["sha256"]
        == json.loads((built / LAYOUT.seal).read_text())["outputs"][
            "results/research_mode/states.parquet"
        ]
    )
    crate = ROCrate(archive)  # ro-crate-py reads the archive as a crate
    assert crate.mainEntity.id == "Snakefile"
    assert crate.get("results/research_mode/rollouts/fast/shard-00000/").type == "Dataset"


def test_the_archive_validates_offline(archive, tmp_path):
    findings = validation.validate(archive, cache_path=tmp_path / "cache" / "http")
    assert findings == [], "\n".join(f.line() for f in findings)


def test_the_archive_unpacked_elsewhere_verifies_and_snakemake_has_nothing_to_do(archive, tmp_path):
    there = tmp_path / "elsewhere"
    there.mkdir()
    with zipfile.ZipFile(archive) as z:
        z.extractall(there)  # file times are the unpacking's, in the archive's order
    env = {k: v for k, v in os.environ.items() if k != "PYTHONPATH"}
    proc = subprocess.run(
        [sys.executable, "-m", "mjtrial.cli", "verify"],
        cwd=there,
        env=env | {"PYTHONPATH": str(there / "src")},  # the unpacked package, not this one
        capture_output=True,
        text=True,
        timeout=600,
    )
    assert proc.returncode == 0, proc.stdout + proc.stderr
    assert "verified: results/research_mode:" in proc.stdout and " 0 stale" in proc.stdout
    # The README's install there (pip install -e .; pip fetches the build backend as the
    # README's does), the dependencies as installed here.
    venv = tmp_path / "venv"
    subprocess.run([sys.executable, "-m", "venv", "--without-pip", str(venv)], check=True)
    python = venv / "bin" / "python"
    site = subprocess.run(
        [python, "-c", "import sysconfig; print(sysconfig.get_paths()['purelib'])"],
        capture_output=True,
        text=True,
        check=True,
    ).stdout.strip()
    Path(site, "dependencies.pth").write_text(sysconfig.get_paths()["purelib"] + "\n")
    subprocess.run(
        [python, "-m", "pip", "install", "-q", "--no-deps", "-e", "."],
        cwd=there,
        env=env,
        check=True,
        capture_output=True,
        timeout=600,
    )
    proc = subprocess.run(
        [python, "-m", "snakemake", "-c2", "-n"],
        cwd=there,
        env=env,
        capture_output=True,
        text=True,
        timeout=600,
    )
    assert proc.returncode == 0, proc.stdout + proc.stderr
    assert "Nothing to be done" in proc.stdout + proc.stderr, proc.stdout + proc.stderr


def test_a_folder_that_does_not_match_its_crate_is_not_archived(built, tmp_path, capsys):
    work = tmp_path / "experiment"
    shutil.copytree(built, work, symlinks=True)
    out = tmp_path / "run.zip"
    args = ["crate", str(work / LAYOUT.root), "--zip", str(out), "--repo-root", str(work)]
    # An edit of the same size: seen while archiving, by the file's sha256.
    report = work / LAYOUT.report
    text = report.read_text()
    at = text.rindex("fast")  # in the report's text, not its stamp
    report.write_text(text[:at] + "FAST" + text[at + 4 :])
    assert cli.main(args) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "report.md: not the file the crate lists" in err[0], err
    assert not out.exists() and not list(tmp_path.glob(".run.zip.tmp-*"))
    # An edit that changes a file's size: seen before anything is written.
    report.write_text(text)
    summary = work / LAYOUT.summary
    summary.write_text(summary.read_text().replace('"successes"', '"successes" ', 1))
    assert cli.main(args) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "analysis/summary.json: contentSize" in err[0], err
    assert not out.exists()

    (work / LAYOUT.crate).unlink()
    assert cli.main(args) == 1
    err = capsys.readouterr().err.strip()
    assert err.endswith("no crate; `snakemake -c2` (or a study's target) writes it"), err


def test_the_archive_holds_only_the_runs_files_each_as_its_seal_records(built, tmp_path, capsys):
    """A file no job wrote is left out, and named; a symbolic link leaving the repository, a
    sealed output replaced by one, and a file slipped into a sealed folder are refused."""
    work = tmp_path / "experiment"
    shutil.copytree(built, work, symlinks=True)
    results = work / LAYOUT.root
    out = tmp_path / "run.zip"
    args = ["crate", str(results), "--repo-root", str(work)]
    (results / "analysis" / "extra_claims.json").write_text('{"success_rate": 1.0}\n')
    outside = tmp_path / "hostname"
    outside.write_text("a file outside the repository\n")
    (results / "figures" / "zz.png").symlink_to(outside)
    for argv in (args, [*args, "--zip", str(out)]):
        assert cli.main(argv) == 1
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and "figures/zz.png: a symbolic link to" in err[0], err
        assert "outside" in err[0] and not out.exists()
    (results / "figures" / "zz.png").unlink()

    assert cli.main(args) == 0
    printed = capsys.readouterr().out
    assert "not the run's (--zip leaves them out):" in printed
    assert "a file no seal lists (analysis/extra_claims.json)" in printed
    assert cli.main([*args, "--zip", str(out)]) == 0
    printed = capsys.readouterr().out
    assert "left out of it:" in printed and "analysis/extra_claims.json" in printed
    with zipfile.ZipFile(out) as z:
        names = z.namelist()
    assert f"{LAYOUT.summary.as_posix()}" in names
    assert not [n for n in names if "extra_claims" in n or "zz.png" in n]
    out.unlink()

    # A sealed output swapped for a link to a copy outside the repository: its bytes are the
    # seal's, but it is not the run's file.
    states = work / LAYOUT.states
    copy = tmp_path / "states.parquet"
    shutil.copy2(states, copy)
    states.unlink()
    states.symlink_to(copy)
    assert cli.main([*args, "--zip", str(out)]) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "states.parquet: a symbolic link to" in err[0], err
    states.unlink()
    shutil.copy2(copy, states)

    # A file slipped into a sealed folder output: the folder is not what its seal records.
    shard = work / LAYOUT.shard_recordings("fast", "00000")
    (shard / "forged.rrd").write_bytes(b"not an episode")
    assert cli.main([*args, "--zip", str(out)]) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "shard-00000: not the file the crate lists" in err[0], err
    assert not out.exists() and not list(tmp_path.glob(".run.zip.tmp-*"))
