"""A model with a mocap body: a target moved per episode with `MocapPosition` is where the
episode's physics has it (MuJoCo's own `framepos` sensor of the body, through `mujoco.rollout`),
and each episode's recording draws it there."""

from __future__ import annotations

import dataclasses

import mujoco
import numpy as np
import pytest
import rerun as rr
from conftest import REPO_ROOT

from mjtrial.recording import write_condition_recordings
from mjtrial.recording.names import body_entity
from mjtrial.sim.engine import iter_batches
from mjtrial.stages.rollout import episode_records, recording_spec
from mjtrial.task import BoundTask, MocapPosition, StateParameter, load_task

# The scaffold's block on a rail, with a mocap target above the line and a sensor of its pose.
TEMPLATE = REPO_ROOT / "src" / "mjtrial" / "templates" / "new_task"
GOAL = """
    <body name="goal" mocap="true" pos="0.5 0 0.2" quat="0.9 0 0 0.3">
      <geom type="sphere" size="0.03" rgba="1 0 0 1"/>
    </body>
  </worldbody>
  <sensor>
    <framepos name="goal" objtype="body" objname="goal"/>
  </sensor>
"""
GOAL_Y = np.array([-0.15, 0.0, 0.05, 0.12])


@pytest.fixture(scope="module")
def bound() -> BoundTask:
    xml = (TEMPLATE / "model.xml").read_text().replace("  </worldbody>\n", GOAL, 1)
    model = mujoco.MjModel.from_xml_string(xml)
    task = load_task(TEMPLATE / "task.py")
    goal = StateParameter("goal_y", "m", -0.2, 0.2, MocapPosition("goal", 1), "the goal's y")
    task = dataclasses.replace(task, state_parameters=(*task.state_parameters, goal))
    return BoundTask.of(task, model)


@pytest.fixture(scope="module")
def batch(bound):
    n = len(GOAL_Y)
    values = {
        "state_id": np.arange(n),
        "mass": np.full(n, 1.0),
        "start": np.zeros(n),
        "goal_y": GOAL_Y,
    }
    condition = {"push_force": 2.0, "push_time": 0.5}
    [batch] = iter_batches(bound, values, condition, thresholds={"short_by": 0.2}, nthread=1)
    return batch


def test_the_episodes_physics_has_the_goal_where_the_state_put_it(batch):
    # sensordata: the goal's framepos at every step, as MuJoCo computes it
    goal = batch.episodes.sensordata[:, :, 0:3]
    np.testing.assert_array_equal(goal[:, :, 1], np.broadcast_to(GOAL_Y[:, None], goal.shape[:2]))
    np.testing.assert_array_equal(goal[:, :, 0], 0.5)


def test_each_recording_draws_the_goal_where_it_was(bound, batch, tmp_path):
    folder = tmp_path / "c"
    n_steps = batch.episodes.physics.shape[1]
    written = write_condition_recordings(
        folder,
        spec=recording_spec(bound, n_steps, 50.0),
        condition="c",
        episodes=episode_records(bound.task, batch),
        stamp={"mjtrial_stamp": 1, "rule": "test_recording_mocap"},
    )
    assert written == len(GOAL_Y)
    model = bound.model
    entity = "/" + body_entity(model, model.body("goal").id)
    for state_id, y in enumerate(GOAL_Y):
        [path] = folder.glob(f"c-state-{state_id:06d}.rrd")
        reader = rr.chunk.RrdReader(str(path))
        [recording] = reader.recordings()
        [pose] = [
            c.to_record_batch()
            for c in reader.store(store=recording).stream().filter(content=entity)
            if c.entity_path == entity and c.is_static
        ]
        names = pose.schema.names
        [[translation]] = pose.column(names.index("Transform3D:translation")).to_pylist()
        [[quaternion]] = pose.column(names.index("Transform3D:quaternion")).to_pylist()
        assert translation == pytest.approx([0.5, y, 0.2], abs=1e-7)  # float32 in Rerun
        w, x, yq, z = model.body_quat[model.body("goal").id]
        assert quaternion == pytest.approx([x, yq, z, w], abs=1e-7)  # Rerun is x-y-z-w
