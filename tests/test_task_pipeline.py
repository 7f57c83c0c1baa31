"""The pipeline and the task the config names (`task:`): what is wired so far."""

from __future__ import annotations

import shutil
from pathlib import Path

import pytest
from conftest import run_snakemake

pytestmark = pytest.mark.end_to_end

RESULTS = Path("results") / "research_mode"
STATES = (RESULTS / "states.parquet").as_posix()


def test_an_edit_to_the_task_file_redraws_the_states_and_is_stale(built, tmp_path):
    """The task declares the state parameters: its file is an input of the states, by
    content (a touch reruns nothing)."""
    from mjtrial.verify import Status, verify_results

    workdir = tmp_path / "copy"
    shutil.copytree(built, workdir, symlinks=True)
    task = workdir / "tasks" / "gantry_lift" / "task.py"
    task.touch()
    assert "Nothing to be done" in run_snakemake(workdir, "-n").stdout
    task.write_text(task.read_text() + "\n# an edit\n")
    plan = run_snakemake(workdir, "-n").stdout
    assert "states" in plan and "Nothing to be done" not in plan
    report = verify_results(
        workdir / RESULTS, config_path=workdir / "config" / "config.yaml", repo_root=workdir
    )
    assert report[STATES].status is Status.STALE, report.format()
    assert "input changed: tasks/gantry_lift/task.py" in report[STATES].reasons
