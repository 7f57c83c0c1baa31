"""The gantry as a task (`tasks/gantry_lift/task.py`) run by `mjtrial.sim.engine` equals the engine
the pipeline ran before tasks existed (`gantry_lift.simulate` with `gantry_lift.taxonomy`),
bit for bit: every column of the rollout table, on evaluation states, both conditions; and its
final states equal the literal `mj_step` reference stepper's."""

from __future__ import annotations

import numpy as np
import pytest
from conftest import REPO_ROOT
from gantry_lift import taxonomy
from gantry_lift.protocol import PROTOCOL, control_sequence
from gantry_lift.simulate import episode_outcomes, iter_episode_batches, reference_episode

from mjtrial.sim.engine import iter_batches
from mjtrial.stages.rollout import rollout_columns
from mjtrial.task import BoundTask, load_task
from mjtrial.task.checks import run_task_code

THRESHOLDS = {
    "lifted_height": 0.03,
    "slip_distance": 0.01,
    "workspace_radius": 0.15,
    "max_tilt": 1.0,
}
# The rollout table's columns before tasks existed, in their order.
TABLE_BEFORE = (
    "state_id",
    "success",
    "final_height",
    "final_x",
    "final_y",
    "steps_simulated",
    "nonfinite",
    "warning",
    "failure_category",
    "peak_slip",
    "peak_carriage_accel",
)


@pytest.fixture(scope="module")
def gantry():
    return BoundTask.of(load_task("tasks/gantry_lift/task.py", repo_root=REPO_ROOT))


def test_the_gantry_table_keeps_its_columns_in_order(gantry):
    assert rollout_columns(gantry.task) == TABLE_BEFORE


@pytest.mark.parametrize("lift_time", [0.15, 1.5])
def test_gantry_task_equals_the_engine_before_tasks(
    gantry, gantry_model, evaluation_states, lift_time
):
    states = evaluation_states[:40]
    columns = TABLE_BEFORE[1:]
    expected = {c: [] for c in columns}
    _, phase = control_sequence(lift_time, timestep=gantry_model.opt.timestep)
    for batch in iter_episode_batches(gantry_model, states, lift_time=lift_time, nthread=2):
        outcome = episode_outcomes(gantry_model, batch, lift_time=lift_time)
        traj = taxonomy.trajectories_from_batch(
            gantry_model, batch, phase=phase, home_xy=(PROTOCOL.home_x, 0.0)
        )
        outcome |= taxonomy.classify(traj, outcome["success"], taxonomy.Thresholds())
        for c in columns:
            expected[c].append(outcome[c])
    values = {p: np.array([getattr(s, p) for s in states]) for p in ("dx", "dy", "yaw", "mass")}
    got = {c: [] for c in columns}
    finals = []
    for batch in iter_batches(
        gantry, values, {"lift_time": lift_time}, thresholds=THRESHOLDS, nthread=2, batch_size=7
    ):
        for c in columns:
            got[c].append(batch.outcome[c])
        finals.append(batch.episodes.physics[:, -1])
    for c in columns:
        np.testing.assert_array_equal(
            np.concatenate(got[c]), np.concatenate(expected[c]), err_msg=c
        )
    failures = np.concatenate(got["failure_category"])
    assert any(f is not None for f in failures)  # the comparison covers the categories
    finals = np.concatenate(finals)
    for i in (0, 17, 39):  # the literal protocol, step by step with mj_step
        physics, _ = reference_episode(gantry_model, states[i], lift_time=lift_time)
        np.testing.assert_array_equal(finals[i], physics[-1])


def test_gantry_task_passes_its_preflight(gantry):
    run_task_code(
        gantry, {"fast": {"lift_time": 0.15}, "slow": {"lift_time": 1.5}}, thresholds=THRESHOLDS
    )
    assert PROTOCOL.hold_time == gantry.task.parameters({"lift_time": 1})["hold_time"]
