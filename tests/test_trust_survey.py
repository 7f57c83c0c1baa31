"""The second hostile survey: each case a way the pipeline or `mjtrial verify` was fooled, or
results were lost; each test failed before its fix."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

from conftest import edit_config, run_snakemake

RESULTS = Path("results") / "research_mode"


def copy_of(built: Path, tmp_path: Path) -> Path:
    workdir = tmp_path / "copy"
    shutil.copytree(built, workdir)
    return workdir


def test_mostly_unhealthy_episodes_make_the_main_verdict_invalid(built, tmp_path):
    """Survey case 9: masses up to 1e30 make most episodes "simulation unhealthy"; the main
    falsifier must say invalid, not refuted, and the report must say so."""
    workdir = copy_of(built, tmp_path)

    def heavy(config):
        config["states"]["ranges"]["mass"] = [0.05, 1e30]
        config["analysis"]["bands"]["mass"] = [0.05, 1.0, 1e30]

    edit_config(workdir, heavy)
    run_snakemake(workdir)
    summary = json.loads((workdir / RESULTS / "analysis" / "summary.json").read_text())
    unhealthy = sum(summary["conditions"][c]["unhealthy"] for c in ("fast", "slow"))
    assert unhealthy > 0
    assert summary["falsifier"]["verdict"] == "invalid"
    assert f"{unhealthy} of 24 episodes unhealthy" in summary["falsifier"]["reason"]
    assert "Verdict: **INVALID**" in (workdir / RESULTS / "report.md").read_text()


def test_an_edit_to_an_include_in_another_folder_reruns_and_is_stale(built, tmp_path):
    """Survey case 1: the robot's XML moved to models/common/ and included from the scene; an
    edit to its force range there is planned for a rerun and verify calls the rollouts stale."""
    from mjtrial.verify import Status, verify_results

    workdir = copy_of(built, tmp_path)
    models = workdir / "models"
    (models / "common").mkdir()
    (models / "gantry_gripper" / "gantry_gripper.xml").rename(models / "common" / "robot.xml")
    scene = models / "gantry_gripper" / "scene.xml"
    scene.write_text(
        scene.read_text().replace('file="gantry_gripper.xml"', 'file="../common/robot.xml"')
    )
    run_snakemake(workdir)
    assert "Nothing to be done" in run_snakemake(workdir, "-n").stdout
    robot = models / "common" / "robot.xml"
    robot.write_text(robot.read_text().replace('forcerange="-18 18"', 'forcerange="-12 12"'))
    plan = run_snakemake(workdir, "-n").stdout
    assert "rollout" in plan and "Nothing to be done" not in plan
    report = verify_results(
        workdir / RESULTS, config_path=workdir / "config" / "config.yaml", repo_root=workdir
    )
    shard = (RESULTS / "rollouts" / "fast" / "shard-00000.parquet").as_posix()
    assert report[shard].status is Status.STALE, report.format()
    assert "models/common/robot.xml" in " ".join(report[shard].reasons)
