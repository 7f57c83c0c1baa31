"""A closed-loop task on gymnasium-robotics' Fetch model that drives the arm through its mocap
weld as the suite does, for the tests of mocap actions, episode setups and policy files."""

from __future__ import annotations

import mujoco
import numpy as np
from conftest import REPO_ROOT

from mjtrial.sim.closed_loop import Timing
from mjtrial.task import (
    ClosedLoop,
    Control,
    JointPosition,
    Measure,
    MocapAction,
    Observation,
    Series,
    StateParameter,
    Task,
)

FETCH = REPO_ROOT / "tasks" / "fetch_pick" / "assets" / "fetch" / "pick_and_place.xml"
NOMINAL = mujoco.MjModel.from_xml_path(str(FETCH))
FINGERS = ("robot0:l_gripper_finger_joint", "robot0:r_gripper_finger_joint")
# pick_and_place.py's initial_qpos (the object's position is the state parameters' origin)
INITIAL_QPOS = {"robot0:slide0": 0.405, "robot0:slide1": 0.48, "robot0:slide2": 0.0}
OBJECT_START = [1.25, 0.53, 0.4, 1.0, 0.0, 0.0, 0.0]


def fetch_setup(model: mujoco.MjModel, data: mujoco.MjData, values) -> None:
    """fetch_env.py's `_env_setup` (gripper_extra_height 0.2, n_substeps 20)."""
    for name, value in INITIAL_QPOS.items():
        data.qpos[model.joint(name).qposadr[0]] = value
    adr = model.joint("object0:joint").qposadr[0]
    data.qpos[adr : adr + 7] = OBJECT_START
    for i in range(model.neq):  # reset_mocap_welds
        if model.eq_type[i] == mujoco.mjtEq.mjEQ_WELD:
            model.eq_data[i, :7] = [0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0]
    mujoco.mj_forward(model, data)
    grip = data.site_xpos[model.site("robot0:grip").id]
    mocap = model.body_mocapid[model.body("robot0:mocap").id]
    data.mocap_pos[mocap] = np.array([-0.498, 0.005, -0.431 + 0.2]) + grip
    data.mocap_quat[mocap] = [1.0, 0.0, 1.0, 0.0]
    for _ in range(10):
        mujoco.mj_step(model, data, nstep=20)


class Wiggle:
    """Elementwise actions: mocap deltas and the gripper, from the object's x and y."""

    def reset(self, n: int) -> None:
        pass

    def __call__(self, obs: np.ndarray) -> np.ndarray:
        x, y = obs.T
        return np.stack([np.sin(40 * x), np.cos(40 * y), -0.5 + 0 * x, np.sin(9 * y)], axis=1)


def fetch_task(setup=fetch_setup, **changes) -> Task:
    """A closed-loop Fetch task driving the arm through its mocap, as the suite does."""
    task = Task(
        name="fetch_mocap",
        title="the Fetch arm moved through its mocap",
        model=FETCH,
        state_parameters=(
            StateParameter("object_dx", "m", -0.1, 0.1, JointPosition("object0:joint", 0)),
            StateParameter("object_dy", "m", -0.1, 0.1, JointPosition("object0:joint", 1)),
        ),
        protocol_parameters=(),
        controller=ClosedLoop(
            policy=lambda model, params: Wiggle(),
            observations=("object_x", "object_y"),
            timing=lambda model, params: Timing(20, 8),
            actions=(
                MocapAction(
                    "robot0:mocap",
                    relative_to="body",
                    scale=0.05,
                    max_step=0.05,
                    orientation_offset=(1.0, 0.0, 1.0, 0.0),
                ),
                Control(FINGERS, relative=True),
            ),
        ),
        success=lambda episodes: episodes.mocap[:, -1, 0, 1] > 0.75,
        measure=lambda episodes: {"final_target_y": episodes.mocap[:, -1, 0, 1]},
        measures=(Measure("final_target_y", "m", "the mocap target's y at the end"),),
        series=(
            Series.joint_position(
                "object x", "object0:joint", body="object0", plot="object position (m)"
            ),
        ),
        observations=(
            Observation.joint_position("object_x", "object0:joint", source=None),
            Observation.joint_position("object_y", "object0:joint", source=None),
        ),
        episode_setup=setup,
    )
    return Task(**{**task.__dict__, **changes})
