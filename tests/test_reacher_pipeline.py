"""The goal-conditioned reach on dm_control's reacher, as shipped, through the whole pipeline:
built from its config, verified (re-simulating episodes), replayed; its report says what is true
of this model (contacts disabled, motors limited by ctrlrange times gear, in N·m)."""

from __future__ import annotations

import hashlib
from pathlib import Path

import pyarrow.parquet as pq
import pytest
import yaml
from conftest import REPO_ROOT, copy_workflow, run_snakemake

from mjtrial.cli import main

pytestmark = pytest.mark.end_to_end

CONFIG = "config/reacher_small.yaml"
RESULTS = "results/reacher_small"
SHIPPED = {  # the model's files as dm_control 1.0.50 ships them (tasks/reacher_goal/README.md)
    "reacher.xml": "849e1e3dd8e79b8f5796bd6e32b0d7a51b916355584402d8f803d74ad35ad193",
    "common/skybox.xml": "71db77c7c88dd4e1b54eb394deecfba673bbf539d110de68aa229dee00abf107",
    "common/visual.xml": "1e338ca511de35b902c4ca944d857c23fe4e7a5aea46a475cdc317dd454245b0",
    "common/materials.xml": "83ee4f7d3f0c9b3003ad121c2c35169a32a922c437321278f27db60d577ccfac",
}


def test_the_model_is_the_one_dm_control_ships():
    folder = REPO_ROOT / "tasks" / "reacher_goal"
    for name, sha256 in SHIPPED.items():
        assert hashlib.sha256((folder / name).read_bytes()).hexdigest() == sha256, name


@pytest.fixture(scope="module")
def reacher_run(tmp_path_factory) -> Path:
    workdir = tmp_path_factory.mktemp("reacher")
    copy_workflow(workdir)
    config = yaml.safe_load((REPO_ROOT / "config" / "reacher_goal.yaml").read_text())
    config["experiment"] = "reacher_small"
    config["states"]["n"] = 16
    config["analysis"]["n_resamples"] = 200
    config["recording"]["episodes"] = "failed"
    (workdir / CONFIG).write_text(yaml.safe_dump(config, sort_keys=False))
    run_snakemake(workdir, "--configfile", CONFIG)
    return workdir


def test_it_verifies_with_episodes_resimulated(reacher_run, monkeypatch, capsys):
    monkeypatch.chdir(reacher_run)
    code = main(["verify", RESULTS, "--config", CONFIG, "--resimulate", "4"])
    assert code == 0, capsys.readouterr().out


def test_a_replay_reproduces_its_row(reacher_run, monkeypatch, capsys):
    monkeypatch.chdir(reacher_run)
    rows = pq.read_table(reacher_run / RESULTS / "rollouts" / "latency_100ms.parquet").to_pylist()
    failed = next(r for r in rows if not r["success"])
    out = reacher_run / "replayed.rrd"
    code = main(
        [
            "replay",
            RESULTS,
            "--condition",
            "latency_100ms",
            "--state",
            str(failed["state_id"]),
            "--output",
            str(out),
            "--no-viewer",
        ]
    )
    assert code == 0, capsys.readouterr()
    assert out.is_file()


def test_the_report_is_true_of_this_model(reacher_run):
    report = (reacher_run / RESULTS / "report.md").read_text()
    assert "- Contacts: disabled in the model's `<option>`; no geom collides." in report
    assert (
        "`shoulder` on joint `shoulder`: force [-0.05, 0.05] N·m (ctrlrange × gain, × gear 0.05)"
        in (report)
    )
    assert "goal_x (the goal the robot is commanded)" in report


def test_each_recording_draws_its_own_goal(reacher_run):
    """The goal moves the model's target geom per episode: a recording draws it where it was."""
    import rerun as rr

    results = reacher_run / RESULTS
    states = {r["state_id"]: r for r in pq.read_table(results / "states.parquet").to_pylist()}
    rows = pq.read_table(results / "rollouts" / "latency_100ms.parquet").to_pylist()
    failed = [r["state_id"] for r in rows if not r["success"]][:3]
    assert failed
    for state_id in failed:
        [path] = (results / "rollouts" / "latency_100ms").glob(f"*/*-{state_id:06d}.rrd")
        reader = rr.chunk.RrdReader(str(path))
        [recording] = reader.recordings()
        [world] = [
            c.to_record_batch()
            for c in reader.store(store=recording).stream().filter(content="/world")
            if c.entity_path == "/world"
        ]
        [centers] = world.column(world.schema.names.index("Ellipsoids3D:centers")).to_pylist()
        goal = [states[state_id]["goal_x"], states[state_id]["goal_y"], 0.01]
        assert centers == [pytest.approx(goal, abs=1e-6)]  # the target, the world's one sphere
