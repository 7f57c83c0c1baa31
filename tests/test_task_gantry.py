"""The gantry experiment stated as a task (tasks/gantry_lift/task.py) gives the pipeline's
episodes bit for bit: every column of the rollout table, on evaluation states, both conditions."""

from __future__ import annotations

import numpy as np
import pytest
from conftest import REPO_ROOT

from mjtrial import taxonomy
from mjtrial.engine import iter_batches
from mjtrial.protocol import PROTOCOL
from mjtrial.stages.rollout import condition_outcomes
from mjtrial.task import BoundTask, load_task
from mjtrial.task_checks import preflight

THRESHOLDS = {
    "lifted_height": 0.03,
    "slip_distance": 0.01,
    "workspace_radius": 0.15,
    "max_tilt": 1.0,
}
COLUMNS = (
    "success",
    "failure_category",
    "final_height",
    "final_x",
    "final_y",
    "steps_simulated",
    "peak_slip",
    "peak_carriage_accel",
)


@pytest.fixture(scope="module")
def gantry():
    return BoundTask.of(load_task("tasks/gantry_lift/task.py", repo_root=REPO_ROOT))


@pytest.mark.parametrize("lift_time", [0.15, 1.5])
def test_gantry_task_equals_the_pipeline_engine(gantry, gantry_model, evaluation_states, lift_time):
    states = evaluation_states[:40]
    expected = {c: [] for c in COLUMNS}
    for _, outcome in condition_outcomes(
        gantry_model, states, lift_time=lift_time, thresholds=taxonomy.Thresholds(), nthread=2
    ):
        for c in COLUMNS:
            expected[c].append(outcome[c])
    values = {p: np.array([getattr(s, p) for s in states]) for p in ("dx", "dy", "yaw", "mass")}
    got = {c: [] for c in COLUMNS}
    for batch in iter_batches(
        gantry, values, {"lift_time": lift_time}, thresholds=THRESHOLDS, nthread=2, batch_size=16
    ):
        for c in COLUMNS:
            got[c].append(batch.outcome[c])
    for c in COLUMNS:
        np.testing.assert_array_equal(
            np.concatenate(got[c]), np.concatenate(expected[c]), err_msg=c
        )
    failures = np.concatenate(got["failure_category"])
    assert any(f is not None for f in failures)  # the comparison covers the categories


def test_gantry_task_passes_its_preflight(gantry):
    preflight(
        gantry, {"fast": {"lift_time": 0.15}, "slow": {"lift_time": 1.5}}, thresholds=THRESHOLDS
    )
    assert PROTOCOL.hold_time == gantry.task.parameters({"lift_time": 1})["hold_time"]
