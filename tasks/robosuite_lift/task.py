"""robosuite's Lift with its Panda, driven as robosuite drives it: an operational-space
controller at every physics step.

Question: does closing the gripper for 100 ms (2 policy actions) before the lift, against 150 ms
(3 actions), lower how often a scripted grasp lifts the cube?

The model is robosuite 1.5.2's Lift exported as built (`models/robosuite_lift/`, its README:
meshes byte for byte from the wheel, nothing changed but asset paths). The policy acts at 20 Hz
(robosuite's `control_freq`): a 7-d action, the grip site's displacement and rotation in
[-1, 1] of 5 cm and 0.5 rad in the robot base's frame, and the gripper's command. Between its
actions, at every 2 ms physics step, robosuite's OSC_POSE and GRIP controllers with their
defaults turn the latest action into the arm's joint torques and the fingers' position targets
from the current site Jacobian, mass matrix and bias forces
(`mjtrial.sim.operational_space.OperationalSpace`, a low-level controller: `mjtrial.sim.low_level`).

Each episode starts as robosuite's reset leaves it: the arm at the Panda's `init_qpos` plus a
Gaussian draw of standard deviation 0.02 rad per joint (`initialization_noise` "default"; the
config's `states.distributions`), the fingers at their initial opening, the cube on the table
within 3 cm of its centre in x and y (the placement sampler's ranges), turned by a yaw drawn
uniformly in [0, 2 pi).

The policy is scripted (`scripted.py`, the same function robosuite's env was run with): above
the cube with the gripper opening, down to it, close for `close_steps` actions, lift at
0.9 of the largest step.

Success: robosuite's `_check_success`, the cube's centre more than 4 cm above the table top,
at the episode's end.
"""

from __future__ import annotations

import mujoco
import numpy as np

from mjtrial.sim.closed_loop import Timing
from mjtrial.sim.operational_space import OperationalSpace
from mjtrial.sim.physics import STATE_QPOS
from mjtrial.task import (
    ClosedLoop,
    Custom,
    Episodes,
    FailureCategory,
    JointPosition,
    Margin,
    Measure,
    Observation,
    ProtocolParameter,
    Series,
    StateParameter,
    Task,
)

from . import scripted
from .osc_reference import (
    ARM_ACTUATORS,
    ARM_JOINTS,
    BASE_SITE,
    GRIP_SITE,
    GRIPPER_ACTUATORS,
    GRIPPER_INIT_QPOS,
    GRIPPER_JOINTS,
    INIT_NOISE_STD,
    INIT_QPOS,
)

CUBE_JOINT, CUBE_BODY, TABLE_TOP = "cube_joint0", "cube_main", "table_top"
N_SUBSTEPS = 25  # physics steps of 2 ms per action: robosuite's control_freq 20 Hz
CUBE_RANGE = 0.03  # m: the placement sampler's x and y ranges about the table's centre
CUBE_Z_OFFSET = 0.01  # m: the sampler's z_offset above the table top
SUCCESS_HEIGHT = 0.04  # m above the table top (robosuite's _check_success)
LIFTED = 0.01  # m: the cube counts as lifted this far above its start
NOISE_RANGE = 4 * INIT_NOISE_STD  # rad: the joint noise's range for the schema and bands
OBSERVATION_LAG = 1  # physics steps: robosuite's observed positions are the last mj_step1's


def _id(model: mujoco.MjModel, kind: mujoco.mjtObj, name: str) -> int:
    return mujoco.mj_name2id(model, kind, name)


def _cube_qpos(model: mujoco.MjModel) -> int:
    return int(model.jnt_qposadr[_id(model, mujoco.mjtObj.mjOBJ_JOINT, CUBE_JOINT)])


def table_height(model: mujoco.MjModel) -> float:
    """The table top's height: its site's, in the table body's frame (neither moves)."""
    site = _id(model, mujoco.mjtObj.mjOBJ_SITE, TABLE_TOP)
    return float(model.body_pos[model.site_bodyid[site]][2] + model.site_pos[site][2])


def episode_setup(model: mujoco.MjModel, data: mujoco.MjData, values) -> None:
    """robosuite's reset before its draws: the arm at `init_qpos`, the fingers at their initial
    opening, the cube upright on the table's centre at the sampler's height (its bottom
    `z_offset` above the top). The draws (joint noise, cube offset and yaw) are the state
    parameters, applied after this."""
    for joint, q in zip(ARM_JOINTS, INIT_QPOS, strict=True):
        data.joint(joint).qpos = q
    for joint, q in zip(GRIPPER_JOINTS, GRIPPER_INIT_QPOS, strict=True):
        data.joint(joint).qpos = q
    cube = _id(model, mujoco.mjtObj.mjOBJ_BODY, CUBE_BODY)
    half_height = model.geom_size[model.body_geomadr[cube]][2]
    adr = _cube_qpos(model)
    data.qpos[adr : adr + 7] = (
        0.0,
        0.0,
        table_height(model) + CUBE_Z_OFFSET + half_height,
        1.0,
        0.0,
        0.0,
        0.0,
    )


def _set_yaw(model: mujoco.MjModel, data: mujoco.MjData, yaw: float) -> None:
    """The sampler's rotation about z (robosuite's (x, y, z, w) quaternion, in MuJoCo's w-x-y-z
    order)."""
    adr = _cube_qpos(model)
    data.qpos[adr + 3 : adr + 7] = (np.cos(yaw / 2), 0.0, 0.0, np.sin(yaw / 2))


def timing(model: mujoco.MjModel, params) -> Timing:
    """25 physics steps an action; the policy reads the state one physics step before its
    instant, as robosuite's observations do: they are MuJoCo's data after the last `mj_step2`,
    whose positions `mj_step1` computed at the state before that step (after a reset, the
    reset's own)."""
    close_steps = int(params["close_steps"])
    return Timing(
        steps_per_control=N_SUBSTEPS,
        n_controls=scripted.episode_steps(close_steps),
        latency_steps=OBSERVATION_LAG,
    )


class ScriptedLift:
    """`scripted.action` on a batch, row by row: an episode's action never depends on its
    batch. Observations: the grip site's and the cube's positions (6 columns)."""

    def __init__(self, close_steps: int) -> None:
        self.close_steps = close_steps
        self.step = 0

    def reset(self, n_episodes: int) -> None:
        self.step = 0

    def __call__(self, observations: np.ndarray) -> np.ndarray:
        out = np.stack(
            [
                scripted.action(self.step, row[:3], row[3:6], self.close_steps)
                for row in observations
            ]
        )
        self.step += 1
        return out.reshape(len(observations), 7)


def operational_space(model: mujoco.MjModel, params) -> OperationalSpace:
    return OperationalSpace(
        model,
        site=GRIP_SITE,
        base_site=BASE_SITE,
        arm_actuators=ARM_ACTUATORS,
        hand_actuators=GRIPPER_ACTUATORS,
    )


def _cube_height(episodes: Episodes) -> np.ndarray:
    """The cube's centre above the table top at every step, (n, n_steps)."""
    adr = STATE_QPOS + _cube_qpos(episodes.model) + 2
    return episodes.physics[:, :, adr] - table_height(episodes.model)


def measure(episodes: Episodes) -> dict[str, np.ndarray]:
    height = _cube_height(episodes)
    start = height[:, 0]
    return {
        "final_height": height[:, -1],
        "peak_lift": height.max(axis=1) - start,
        "height_margin": height[:, -1] - SUCCESS_HEIGHT,
    }


def success(episodes: Episodes) -> np.ndarray:
    return measure(episodes)["height_margin"] > 0.0


def _cube_height_series(model: mujoco.MjModel):
    adr = STATE_QPOS + _cube_qpos(model) + 2
    top = table_height(model)
    return lambda rows, sensors, ctrl: rows[:, adr] - top


def _joint_noise(k: int) -> StateParameter:
    return StateParameter(
        f"joint{k + 1}_noise",
        "rad",
        -NOISE_RANGE,
        NOISE_RANGE,
        JointPosition(ARM_JOINTS[k]),
        f"joint {k + 1}'s offset from init_qpos (robosuite: normal, std {INIT_NOISE_STD:g})",
        nominal=0.0,
    )


TASK = Task(
    name="robosuite_lift",
    title="a cube lifted by robosuite's Panda under its operational-space controller",
    model="../../models/robosuite_lift/lift.xml",
    state_parameters=(
        StateParameter(
            "cube_dx",
            "m",
            -CUBE_RANGE,
            CUBE_RANGE,
            JointPosition(CUBE_JOINT, 0),
            "the cube's x offset from the table's centre",
            nominal=0.0,
        ),
        StateParameter(
            "cube_dy",
            "m",
            -CUBE_RANGE,
            CUBE_RANGE,
            JointPosition(CUBE_JOINT, 1),
            "the cube's y offset from the table's centre",
            nominal=0.0,
        ),
        StateParameter(
            "cube_yaw",
            "rad",
            0.0,
            2 * np.pi,
            Custom(_set_yaw),
            "the cube's yaw about the vertical",
            nominal=0.0,
        ),
        *(_joint_noise(k) for k in range(len(ARM_JOINTS))),
    ),
    protocol_parameters=(
        ProtocolParameter(
            "close_steps",
            "actions",
            3,
            minimum=1,
            maximum=20,
            integer=True,
            description="policy actions the gripper closes for, holding still, before the lift",
        ),
    ),
    controller=ClosedLoop(
        policy=lambda model, params: ScriptedLift(int(params["close_steps"])),
        observations=("grip_position", "cube_position"),
        timing=timing,
        low_level=operational_space,
    ),
    observations=(
        Observation.site_position(
            "grip_position", GRIP_SITE, source="joint encoders and kinematics"
        ),
        Observation.body_position("cube_position", CUBE_BODY, source="a camera pose estimate"),
    ),
    episode_setup=episode_setup,
    setup_edits_model=False,
    success=success,
    success_text=(
        f"the cube's centre more than {SUCCESS_HEIGHT:g} m above the table top at the end"
    ),
    measure=measure,
    measures=(
        Measure(
            "final_height", "m", "the cube's centre above the table top at the end", recorded=True
        ),
        Measure("peak_lift", "m", "the cube's highest rise above its start"),
        Measure("height_margin", "m", "the final height less the success height"),
    ),
    margin=Margin("height_margin", 0.0, above=True),
    failure_categories=(
        FailureCategory(
            "never lifted",
            f"the cube never rose {LIFTED:g} m: the grasp missed or did not hold at all",
            lambda m, t: m["peak_lift"] < LIFTED,
        ),
        FailureCategory(
            "slipped",
            "the cube rose but ended below the success height: it slipped out of the grasp",
            lambda m, t: m["final_height"] <= SUCCESS_HEIGHT,
        ),
    ),
    series=(
        Series("cube_height", CUBE_BODY, "cube height above the table (m)", _cube_height_series),
        Series.joint_position(
            "left_finger",
            GRIPPER_JOINTS[0],
            body="gripper0_right_leftfinger",
            plot="finger position (m)",
        ),
        Series.joint_position(
            "right_finger",
            GRIPPER_JOINTS[1],
            body="gripper0_right_rightfinger",
            plot="finger position (m)",
        ),
    ),
    limitations=(
        "One scripted policy; a learned one may close and lift differently.",
        "The policy reads positions 2 ms old, as robosuite's observations hold them; an "
        "observation of a joint position would be 2 ms old here too, where robosuite's is not.",
    ),
)
