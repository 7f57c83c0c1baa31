"""Pick and place with gymnasium-robotics' Fetch, as shipped: a mocap-driven arm.

Question: does 4 cm of noise in the sensed position of the block, against 2.5 cm, lower how often
a scripted pick-and-place controller puts the block within 5 cm of a goal drawn per episode?

The model is the suite's own `fetch/pick_and_place.xml` (gymnasium-robotics 1.4.2, byte for
byte, `README.md` beside it); nothing is added to it. It is driven as the suite drives it
(`MujocoFetchEnv._set_action`, `mujoco_utils.mocap_set_action` and `ctrl_set_action`): each
control step (20 physics steps of 2 ms) the mocap body welded to the gripper is put on the
gripper's current pose plus a position delta of at most 5 cm, with the suite's fixed
orientation, and the two finger servos are set to the fingers' position plus the gripper
action. Each episode starts as the suite's `reset` leaves it (`episode_setup`: `_env_setup`'s
arm pose, weld reset and ten settling steps, then the block and the goal placed from the
episode's state values), with the suite's draws: the block within 15 cm of the gripper in x and
y, redrawn when closer than 10 cm (`valid_state`); the goal within 15 cm of the gripper in x and
y, on the table for half the episodes and up to 45 cm above it for the other half.

The controller is scripted, as the suite's demonstrations are: over the block with the fingers
open, down, close, carry to the goal. It reads the gripper's position (its joints' encoders
through forward kinematics), the block's position through a camera pose estimate with Gaussian
noise (`object_noise`, per reading) and the goal it is commanded.

Success: the block's centre within 5 cm of the goal at the end of the 50 control steps (2 s),
the suite's `distance_threshold` and episode length.
"""

from __future__ import annotations

import copy

import mujoco
import numpy as np

from mjtrial.sim.closed_loop import Timing
from mjtrial.sim.physics import STATE_QPOS
from mjtrial.task import (
    EPISODE_SETUP,
    ClosedLoop,
    Control,
    Episodes,
    FailureCategory,
    Margin,
    Measure,
    MocapAction,
    Observation,
    ProtocolParameter,
    Series,
    StateParameter,
    Task,
)

# The model's elements (assets/fetch/robot.xml, pick_and_place.xml).
MOCAP, HAND = "robot0:mocap", "robot0:gripper_link"
GRIP, OBJECT_SITE, GOAL_SITE = "robot0:grip", "object0", "target0"
OBJECT_JOINT, OBJECT_BODY = "object0:joint", "object0"
FINGERS = ("robot0:l_gripper_finger_joint", "robot0:r_gripper_finger_joint")  # the servos' names
# The suite's FetchPickAndPlace-v4 settings (envs/fetch/pick_and_place.py, fetch_env.py).
ARM_START = {"robot0:slide0": 0.405, "robot0:slide1": 0.48, "robot0:slide2": 0.0}
OBJECT_START = (1.25, 0.53, 0.4, 1.0, 0.0, 0.0, 0.0)
GRIPPER_EXTRA_HEIGHT = 0.2  # m above the table
GRIPPER_OFFSET = np.array([-0.498, 0.005, -0.431 + GRIPPER_EXTRA_HEIGHT])  # from the grip site
GRIPPER_QUAT = (1.0, 0.0, 1.0, 0.0)  # the suite's fixed end-effector rotation (as it adds it)
N_SUBSTEPS = 20  # physics steps per control step (2 ms each: 40 ms)
SETUP_STEPS = 10  # control steps `_env_setup` runs to bring the gripper into place
MAX_STEP = 0.05  # m: the largest mocap move per control step (`pos_ctrl *= 0.05`)
OBJECT_RANGE = 0.15  # m: the block's offset from the gripper, each of x and y
MIN_OBJECT_DISTANCE = 0.1  # m: closer draws are redrawn
TARGET_RANGE = 0.15  # m: the goal's offset from the gripper, each of x and y
MAX_LIFT = 0.45  # m: a goal in the air is up to this high above the table
DISTANCE_THRESHOLD = 0.05  # m: success
EPISODE_CONTROLS = 50  # the suite's max_episode_steps
# The scripted controller.
APPROACH_HEIGHT = 0.05  # m above the block before going down
ALIGNED = 0.01  # m: close enough in x-y (over the block) and in z (at the block)
CLOSING_STEPS = 3  # control steps to close the fingers before carrying
GAIN = 10.0  # action per metre of position error (clipped to [-1, 1])
LIFTED = 0.01  # m: the block counts as lifted this far above its start


def _id(model: mujoco.MjModel, kind: mujoco.mjtObj, name: str) -> int:
    return mujoco.mj_name2id(model, kind, name)


def settle(model: mujoco.MjModel, data: mujoco.MjData) -> tuple[np.ndarray, float]:
    """`_env_setup`: the arm's start pose, the mocap welds reset to identity, the gripper brought
    into place by its mocap over ten control steps. Returns where the grip site and the block's
    centre height came to rest (`initial_gripper_xpos`, `height_offset`)."""
    for joint, q in ARM_START.items():
        data.joint(joint).qpos = q
    data.joint(OBJECT_JOINT).qpos = OBJECT_START
    welds = model.eq_type == mujoco.mjtEq.mjEQ_WELD
    model.eq_data[welds, :7] = (0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0)  # reset_mocap_welds
    mujoco.mj_forward(model, data)
    data.mocap_pos[0] = GRIPPER_OFFSET + data.site(GRIP).xpos
    data.mocap_quat[0] = GRIPPER_QUAT
    for _ in range(SETUP_STEPS):
        mujoco.mj_step(model, data, nstep=N_SUBSTEPS)
    return data.site(GRIP).xpos.copy(), float(data.site(OBJECT_SITE).xpos[2])


def goals(grip: np.ndarray, height: float, values) -> np.ndarray:
    """`_sample_goal`: (n, 3) goals from the gripper's rest position, on the table or above."""
    dx, dy = np.atleast_1d(values["goal_dx"]), np.atleast_1d(values["goal_dy"])
    lift = np.maximum(0.0, np.atleast_1d(values["goal_lift"]))
    return np.column_stack([grip[0] + dx, grip[1] + dy, height + lift])


def episode_setup(model: mujoco.MjModel, data: mujoco.MjData, values) -> None:
    """The suite's reset: `settle` (`_env_setup`), then `_reset_sim` (the settled pose restored
    with zero warm start and controls, the block placed) and the goal site put on the goal."""
    grip, height = settle(model, data)
    qpos, qvel, time = data.qpos.copy(), data.qvel.copy(), data.time
    mujoco.mj_resetData(model, data)
    data.qpos[:], data.qvel[:], data.time = qpos, qvel, time
    data.joint(OBJECT_JOINT).qpos[:2] = grip[:2] + (values["object_dx"], values["object_dy"])
    target = _id(model, mujoco.mjtObj.mjOBJ_SITE, GOAL_SITE)
    parent = model.site_bodyid[target]  # the goal site's body has no rotation (floor0)
    model.site_pos[target] = goals(grip, height, values)[0] - model.body_pos[parent]
    mujoco.mj_forward(model, data)


def rest_pose(model: mujoco.MjModel) -> tuple[np.ndarray, float]:
    """`settle` on a copy: where the gripper and the block rest before an episode's draws."""
    copied = copy.copy(model)
    return settle(copied, mujoco.MjData(copied))


def valid_state(values) -> np.ndarray:
    """The suite redraws a block closer than 10 cm to the gripper (`_reset_sim`)."""
    return np.hypot(values["object_dx"], values["object_dy"]) >= MIN_OBJECT_DISTANCE


def timing(model: mujoco.MjModel, params) -> Timing:
    return Timing(steps_per_control=N_SUBSTEPS, n_controls=EPISODE_CONTROLS)


class ScriptedPickAndPlace:
    """Over the block with the fingers open, down to it, close, carry to the goal: a phase per
    episode, each row computed from that row alone (an episode's action never depends on its
    batch)."""

    def __init__(self) -> None:
        self.phase = np.zeros(0, dtype=int)
        self.closing = np.zeros(0, dtype=int)

    def reset(self, n_episodes: int) -> None:
        self.phase = np.zeros(n_episodes, dtype=int)
        self.closing = np.zeros(n_episodes, dtype=int)

    def __call__(self, observations: np.ndarray) -> np.ndarray:
        grip, block, goal = observations[:, 0:3], observations[:, 3:6], observations[:, 6:9]
        over = np.hypot(*(grip[:, :2] - block[:, :2]).T) < ALIGNED
        self.phase = np.where((self.phase == 0) & over, 1, self.phase)
        down = np.abs(grip[:, 2] - block[:, 2]) < ALIGNED
        self.phase = np.where((self.phase == 1) & down, 2, self.phase)
        self.closing = self.closing + (self.phase == 2)
        self.phase = np.where((self.phase == 2) & (self.closing > CLOSING_STEPS), 3, self.phase)
        target = np.where(
            (self.phase == 0)[:, None],
            block + (0.0, 0.0, APPROACH_HEIGHT),
            np.where((self.phase == 3)[:, None], goal, block),
        )
        fingers = np.where(self.phase >= 2, -1.0, 1.0)
        return np.clip(np.column_stack([GAIN * (target - grip), fingers]), -1.0, 1.0)


def _object(episodes: Episodes) -> np.ndarray:
    """The block's centre at every step, (n, n_steps, 3), from its free joint."""
    adr = (
        STATE_QPOS
        + episodes.model.jnt_qposadr[_id(episodes.model, mujoco.mjtObj.mjOBJ_JOINT, OBJECT_JOINT)]
    )
    return episodes.physics[:, :, adr : adr + 3]


def measure(episodes: Episodes) -> dict[str, np.ndarray]:
    block = _object(episodes)
    goal = goals(*rest_pose(episodes.model), episodes.values)
    distance = np.linalg.norm(block[:, -1] - goal, axis=1)
    return {
        "final_distance": distance,
        "peak_lift": block[:, :, 2].max(axis=1) - block[:, 0, 2],
        "distance_left": DISTANCE_THRESHOLD - distance,
    }


def success(episodes: Episodes) -> np.ndarray:
    return measure(episodes)["distance_left"] > 0.0


def _block_height(model: mujoco.MjModel):
    adr = STATE_QPOS + model.jnt_qposadr[_id(model, mujoco.mjtObj.mjOBJ_JOINT, OBJECT_JOINT)]
    return lambda rows, sensors, ctrl: rows[:, adr + 2]


TASK = Task(
    name="fetch_pick",
    title="a block picked and placed by gymnasium-robotics' Fetch arm, driven by its mocap",
    model="assets/fetch/pick_and_place.xml",
    state_parameters=(
        StateParameter(
            "object_dx",
            "m",
            -OBJECT_RANGE,
            OBJECT_RANGE,
            EPISODE_SETUP,
            "the block's x offset from the gripper at rest",
            nominal=0.1,
        ),
        StateParameter(
            "object_dy",
            "m",
            -OBJECT_RANGE,
            OBJECT_RANGE,
            EPISODE_SETUP,
            "the block's y offset from the gripper at rest",
        ),
        StateParameter(
            "goal_dx",
            "m",
            -TARGET_RANGE,
            TARGET_RANGE,
            EPISODE_SETUP,
            "the goal's x offset from the gripper at rest",
        ),
        StateParameter(
            "goal_dy",
            "m",
            -TARGET_RANGE,
            TARGET_RANGE,
            EPISODE_SETUP,
            "the goal's y offset from the gripper at rest",
        ),
        StateParameter(
            "goal_lift",
            "m",
            -MAX_LIFT,
            MAX_LIFT,
            EPISODE_SETUP,
            "the goal's height above the table where positive (on it otherwise)",
        ),
    ),
    protocol_parameters=(
        ProtocolParameter(
            "object_noise",
            "m",
            0.0,
            minimum=0.0,
            maximum=0.2,
            description="standard deviation of the sensed block position's noise",
        ),
    ),
    controller=ClosedLoop(
        policy=lambda model, params: ScriptedPickAndPlace(),
        observations=("grip_position", "block_position", "goal_position"),
        timing=timing,
        actions=(
            MocapAction(
                MOCAP,
                relative_to="body",
                scale=MAX_STEP,
                max_step=MAX_STEP,
                orientation_offset=GRIPPER_QUAT,
            ),
            Control(FINGERS, relative=True),
        ),
    ),
    observations=(
        Observation.site_position("grip_position", GRIP, source="joint encoders and kinematics"),
        Observation.site_position(
            "block_position", OBJECT_SITE, source="a camera pose estimate", noise="object_noise"
        ),
        Observation.site_position(
            "goal_position", GOAL_SITE, source="the goal the robot is commanded"
        ),
    ),
    episode_setup=episode_setup,
    valid_state=valid_state,
    success=success,
    success_text=f"the block's centre within {DISTANCE_THRESHOLD:g} m of the goal at the end",
    measure=measure,
    measures=(
        Measure("final_distance", "m", "the block's centre to the goal at the end", recorded=True),
        Measure("peak_lift", "m", "the block's highest rise above its start"),
        Measure("distance_left", "m", "the threshold less the final distance"),
    ),
    margin=Margin("distance_left", 0.0, above=True),
    failure_categories=(
        FailureCategory(
            "never lifted",
            f"the block never rose {LIFTED:g} m and ended away from the goal",
            lambda m, t: m["peak_lift"] < LIFTED,
        ),
        FailureCategory(
            "not placed",
            "the block was lifted but ended away from the goal (dropped, or still on its way)",
            lambda m, t: m["final_distance"] >= DISTANCE_THRESHOLD,
        ),
    ),
    series=(
        Series("block_height", OBJECT_BODY, "block height (m)", _block_height),
        Series.joint_position(
            "right_finger",
            FINGERS[1],
            body="robot0:r_gripper_finger_link",
            plot="finger opening (m)",
        ),
        Series.joint_position(
            "left_finger",
            FINGERS[0],
            body="robot0:l_gripper_finger_link",
            plot="finger opening (m)",
        ),
    ),
    limitations=(
        "One scripted controller; a learned policy may tolerate sensing noise differently.",
        "The noise is white, per reading; a camera's error is often correlated over time.",
    ),
)
