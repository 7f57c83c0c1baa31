"""A task offered by an installed package through the entry point group `mjtrial.tasks`, as a
lab's own package would: a distribution's metadata on the path names the module defining TASK."""

from __future__ import annotations

import sys

from conftest import REPO_ROOT

from mjtrial.task import ENTRY_POINT_GROUP, load_task

CARTPOLE = REPO_ROOT / "tasks" / "cartpole_latency"


def test_an_installed_package_offers_a_task_by_entry_point(tmp_path, monkeypatch):
    package = tmp_path / "lab_tasks"
    package.mkdir()
    source = (CARTPOLE / "task.py").read_text()
    (package / "__init__.py").write_text(
        source.replace('model="cartpole.xml"', f'model="{CARTPOLE / "cartpole.xml"}"')
    )
    dist = tmp_path / "lab_tasks-0.1.dist-info"
    dist.mkdir()
    (dist / "METADATA").write_text("Metadata-Version: 2.1\nName: lab-tasks\nVersion: 0.1\n")
    (dist / "entry_points.txt").write_text(f"[{ENTRY_POINT_GROUP}]\nlab_balance = lab_tasks\n")
    monkeypatch.syspath_prepend(str(tmp_path))
    try:
        task = load_task("lab_balance")
    finally:
        sys.modules.pop("lab_tasks", None)
    assert ENTRY_POINT_GROUP == "mjtrial.tasks"
    assert task.name == "cartpole_latency"
    assert task.model == CARTPOLE / "cartpole.xml"
    assert task.source == package / "__init__.py"
