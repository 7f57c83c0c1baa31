"""A condition may change the timestep (`conditions.<name>.model.option.timestep`): its episodes
have another number of steps and another time axis than the nominal model's, and the report,
`mjtrial verify` and `mjtrial replay` must read them on the condition's own model.
"""

from __future__ import annotations

import subprocess
from pathlib import Path

import numpy as np
import pytest
import yaml
from conftest import REPO_ROOT, SNAKEMAKE, copy_workflow, run_snakemake

from mjtrial import recording
from mjtrial.replay import replay_episode
from mjtrial.report.traces import sample_traces
from mjtrial.sim.physics import load_model
from mjtrial.stages.condition import condition_task
from mjtrial.stages.stamping import config_slice
from mjtrial.task import BoundTask, load_task

pytestmark = pytest.mark.end_to_end

COARSE = 0.004  # s: twice the gantry's 2 ms
RESULTS = Path("results") / "coarse_step"


def _config() -> dict:
    config = yaml.safe_load((REPO_ROOT / "config" / "config.yaml").read_text())
    config["experiment"] = "coarse_step"
    config["states"]["n"] = 16
    config["analysis"]["n_resamples"] = 300
    config["conditions"]["fast"]["model"] = {"option": {"timestep": COARSE}}
    config.pop("sweep", None)
    config.pop("variants", None)
    return config


@pytest.fixture(scope="module")
def run(tmp_path_factory) -> Path:
    workdir = tmp_path_factory.mktemp("coarse")
    copy_workflow(workdir)
    (workdir / "config" / "config.yaml").write_text(yaml.safe_dump(_config(), sort_keys=False))
    run_snakemake(workdir)
    return workdir


def test_the_report_builds_and_verifies(run):
    assert (run / RESULTS / "report.md").is_file()
    verify = subprocess.run(
        [str(Path(SNAKEMAKE).with_name("mjtrial")), "verify", str(RESULTS)],
        cwd=run,
        capture_output=True,
        text=True,
        timeout=600,
    )
    assert verify.returncode == 0, verify.stdout + verify.stderr


def test_a_replay_of_the_coarse_condition_is_timed_on_its_own_timestep(run):
    out = run / RESULTS / "replay" / "fast-0.rrd"
    replay_episode(condition="fast", state_id=0, output=out, repo_root=run)
    logged = recording.read_episode(out, condition="fast", state_id=0)
    # every physics step logged (full rate), each 4 ms after the one before
    assert np.array_equal(logged["step"], np.arange(len(logged["step"])))
    assert np.allclose(np.diff(logged["time"]), COARSE, atol=1e-9)


def test_the_traces_time_axis_is_the_recorded_one(run):
    config = yaml.safe_load((run / "config" / "config.yaml").read_text())
    model_file = run / config["model"]
    fast = condition_task(
        config_slice("rollout", config, condition="fast"), model_file, repo_root=run
    )
    rollouts = run / RESULTS / "rollouts"
    traces = sample_traces(
        bound=BoundTask.of(load_task(config["task"], repo_root=run), load_model(model_file)),
        rollout_tables={"fast": rollouts / "fast.parquet"},
        recordings={"fast": sorted((rollouts / "fast").glob("shard-*"))},
        conditions={"fast": config["conditions"]["fast"]},
        condition_bounds={"fast": fast},
    )["fast"]
    [state_id, *_] = traces.state_ids
    logged = recording.read_episode(rollouts / "fast", condition="fast", state_id=state_id)
    assert np.allclose(traces.time, logged["time"], atol=1e-9)
