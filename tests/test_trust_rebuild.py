"""The third hostile survey, what is rebuilt and what is kept: a task's data file is an input, a
deleted output is rebuilt, recordings switched off leave none behind, a `touch` of a large
input reruns nothing, a failed run leaves the last good run's results. Each test failed before
its fix."""

from __future__ import annotations

import re
import shutil
import subprocess
from pathlib import Path

import pytest
from conftest import SNAKEMAKE, edit_config, run_snakemake
from test_nothing_lost import digest
from test_trust import assert_same_data

from mjtrial.files.layout import Layout
from mjtrial.task import task_files
from mjtrial.verify import Status, verify_results

pytestmark = pytest.mark.end_to_end

LAYOUT = Layout.of("research_mode")
PROFILE = Path(__file__).resolve().parents[1] / "profiles" / "default" / "config.yaml"


def copy_of(built: Path, tmp_path: Path) -> Path:
    workdir = tmp_path / "copy"
    shutil.copytree(built, workdir, symlinks=True)
    return workdir


def verified(workdir: Path):
    return verify_results(
        workdir / LAYOUT.root, config_path=workdir / "config" / "config.yaml", repo_root=workdir
    )


def planned(workdir: Path, *args: str) -> dict[str, int]:
    """The jobs `snakemake -n` plans, by rule."""
    out = run_snakemake(workdir, "-n", *args).stdout
    table = out.split("Job stats:")[1] if "Job stats:" in out else ""
    return {
        m[1]: int(m[2])
        for m in re.finditer(r"^(\w+)\s+(\d+)$", table, re.MULTILINE)
        if m[1] != "total"
    }


def test_a_data_file_beside_the_task_is_an_input(built, tmp_path):
    """Survey case 2: a file the task reads (not a `.py`) edited: `snakemake -n` had nothing to
    do, and verify blamed untouched outputs. Caches and hidden files are not the task's."""
    workdir = copy_of(built, tmp_path)
    folder = workdir / "tasks" / "gantry_lift"
    (folder / "__pycache__").mkdir(exist_ok=True)
    (folder / "__pycache__" / "x.cpython-311.pyc").write_bytes(b"cache")
    (folder / ".task.py.swp").write_text("an editor's")
    assert planned(workdir) == {}
    (folder / "tol.json").write_text('{"tolerance": 0.01}\n')
    names = [p.name for p in task_files(folder / "task.py")]
    assert "tol.json" in names and "x.cpython-311.pyc" not in names and ".task.py.swp" not in names
    plan = planned(workdir)
    assert {"states", "rollout", "gather", "analysis", "report", "seal"} <= set(plan), plan
    report = verified(workdir)
    states = report[LAYOUT.states.as_posix()]
    assert states.status is Status.STALE, report.format()
    assert "tol.json" in " ".join(states.reasons), report.format()
    assert report.with_status(Status.TAMPERED) == [], report.format()


def test_a_deleted_shard_and_recordings_folder_are_rebuilt_with_what_reads_them(built, tmp_path):
    """Survey case 8: a deleted shard table (read by its gather only) was never rebuilt:
    `snakemake -c2` had nothing to do while verify said missing."""
    workdir = copy_of(built, tmp_path)
    episodes = sorted(
        p.name for p in (workdir / LAYOUT.shard_recordings("slow", "00000")).iterdir()
    )
    (workdir / LAYOUT.shard_table("fast", "00001")).unlink()
    shutil.rmtree(workdir / LAYOUT.shard_recordings("slow", "00000"))
    plan = planned(workdir)
    assert plan["rollout"] == 2 and {"gather", "analysis", "seal", "crate"} <= set(plan), plan
    run_snakemake(workdir)
    assert_same_data(built / LAYOUT.root, workdir / LAYOUT.root)
    folder = workdir / LAYOUT.shard_recordings("slow", "00000")
    assert sorted(p.name for p in folder.iterdir()) == episodes
    assert planned(workdir) == {}
    assert verified(workdir).ok, verified(workdir).format()


def test_switching_recordings_off_leaves_no_old_recordings_to_read(built, tmp_path):
    """Survey case 9: `recording.episodes: none` after a run with `all`, and a condition
    changed: the report read the old recordings and failed ("the rollouts are stale")."""
    workdir = copy_of(built, tmp_path)

    def off_and_later(config):
        config["recording"]["episodes"] = "none"
        config["conditions"]["fast"]["lift_time"] = 0.2

    edit_config(workdir, off_and_later)
    run_snakemake(workdir)
    rollouts = workdir / LAYOUT.rollouts_dir()
    assert [p for p in rollouts.rglob("*") if p.is_dir() and p.name.startswith("shard-")] == []
    assert planned(workdir) == {}
    assert verified(workdir).ok, verified(workdir).format()


def test_a_touch_of_an_input_over_a_megabyte_reruns_nothing(tmp_path):
    """Survey case 10: Snakemake compares an input's sha256 with the one it recorded only up to
    `max-checksum-file-size` (1 MB by default); past it the input's time decides, and a
    `touch` of the failure replays (7.5 MB at N = 200) planned the manifest, report, seal and
    crate again. Under the workflow's profile, a large input is judged by its content."""
    (tmp_path / "profiles" / "default").mkdir(parents=True)
    shutil.copy(PROFILE, tmp_path / "profiles" / "default" / "config.yaml")
    (tmp_path / "Snakefile").write_text(
        "rule all:\n    input: 'b.txt'\n\n"
        "rule big:\n    output: 'a.bin'\n"
        "    run:\n        open(output[0], 'wb').write(bytes(3_000_000))\n\n"
        "rule reads_it:\n    input: 'a.bin'\n    output: 'b.txt'\n"
        "    run:\n        open(output[0], 'w').write('read')\n"
    )

    def plan() -> str:
        proc = subprocess.run(
            [SNAKEMAKE, "-n"], cwd=tmp_path, capture_output=True, text=True, timeout=120
        )
        assert proc.returncode == 0, proc.stderr
        return proc.stdout

    run = subprocess.run([SNAKEMAKE], cwd=tmp_path, capture_output=True, text=True, timeout=120)
    assert run.returncode == 0, run.stderr
    assert "Nothing to be done" in plan()
    for name in ("a.bin", "Snakefile"):
        (tmp_path / name).touch()
    assert "Nothing to be done" in plan()
    (tmp_path / "a.bin").write_bytes(bytes(2_999_999) + b"x")  # an edit is still seen
    assert "reads_it" in plan()


FAIL_IN_ROLLOUTS = """
import os as _os
import sys as _sys

if _os.environ.get("MJTRIAL_TEST_FAIL") and "rollout" in _os.path.basename(_sys.argv[0]):
    raise RuntimeError("a rollout failing at run time")
"""


def test_a_failed_run_leaves_the_last_good_runs_results(built, tmp_path):
    """Survey case 15: a new states seed; the states job succeeded, the rollouts failed; the
    new states table stayed beside the old rollouts, report and seal (consistent with none of
    them). Every output the failed run removed or rebuilt is put back, with its record, so the
    folder is the last good run's."""
    workdir = copy_of(built, tmp_path)
    before = digest(workdir / LAYOUT.root)
    config = workdir / "config" / "config.yaml"
    task = workdir / "tasks" / "gantry_lift" / "task.py"
    original_config, original_task = config.read_text(), task.read_text()
    edit_config(workdir, lambda c: c["states"].update(seed=2027))
    task.write_text(original_task + FAIL_IN_ROLLOUTS)
    proc = run_snakemake(workdir, check=False, env={"MJTRIAL_TEST_FAIL": "1"})
    assert proc.returncode != 0
    # whichever rollout Snakemake ran first failed, and said why in its log
    logs = (workdir / LAYOUT.log("rollout_fast_00000")).parent.glob("rollout_*.log")
    assert any("a rollout failing at run time" in log.read_text() for log in logs)
    assert "put back" in proc.stderr and "states.parquet" in proc.stderr, proc.stderr
    after = digest(workdir / LAYOUT.root)
    # the failed run's new seed is on the record as a deviation from the registration
    assert "deviations.json" in after and "deviations.json" not in before
    after.pop("deviations.json")
    assert after == before
    config.write_text(original_config)
    task.write_text(original_task)
    assert planned(workdir) == {}  # the records came back with the outputs
    assert verified(workdir).ok, verified(workdir).format()
