"""robosuite 1.5.2's controllers for Lift's Panda, written out in numpy and MuJoCo alone.

robosuite drives the arm with OSC_POSE (`controllers/parts/arm/osc.py`, `controller.py`,
`utils/control_utils.py`, `utils/transform_utils.py`; its defaults from
`controllers/config/robots/default_panda.json`) and the fingers with GRIP
(`controllers/parts/gripper/simple_grip.py`, after `PandaGripper.format_action`). This module
is that arithmetic, term for term and in robosuite's order, for one episode, so that a plain
MuJoCo loop reproduces robosuite's env (`models/robosuite_lift/check_reference.py` measures how
closely). Derived from robosuite (MIT licence, `models/robosuite_lift/LICENSE`).

The plain loop that reproduces robosuite's `env.step(action)` (`lite_physics=True`, the
default; `control_freq` 20 Hz; the model's 2 ms timestep, so 25 physics steps an action):

    ids = Ids.of(model)
    state = start(model, data, ids)           # data: the reset state, after mj_forward
    for each policy action a (7 numbers: dx, dy, dz, dax, day, daz in [-1, 1], gripper):
        for i in range(25):
            mujoco.mj_step1(model, data)      # positions, velocities: J, M, bias, site poses
            data.ctrl[:] = ctrl(model, data, ids, state, a, new_action=(i == 0))
            mujoco.mj_step2(model, data)      # actuation, constraint solve, integration

(`episode` below is that loop.)
`mj_step` is never called and `mj_forward` never between steps: robosuite's `sim.step1()`,
its controllers, `sim.step2()`. So every quantity the controller reads is MuJoCo's from
`mj_step1` of this physics step: the grip site's pose and Jacobian (`mj_jacSite`), the mass
matrix (`mj_fullM`, the arm's 7 dofs), the bias forces `qfrc_bias` (gravity, Coriolis), the
joint positions and velocities. The goal is set only at a new action (`new_action`), from the
site's pose then ("achieved" mode: the new goal is the current pose plus the delta, not the
last goal plus it), in the frame of the site `robot0_right_center` (input_ref_frame "base");
the torques are recomputed at every physics step toward that goal. The solver's warm start is
MuJoCo's own, carried from step to step within the episode (one MjData for the episode,
robosuite's `sim.data`); an episode starts from a fresh `MjData` (`hard_reset`) or
`mj_resetData`, so from a zero warm start.

Every torque goes through the arm's motor actuators (`robot0_torq_j1..7`, gear 1, ctrl = the
torque, clipped to ctrlrange +-80 / +-12 N m by robosuite's `Robot.control`), gravity
compensation included: nothing is written to `qfrc_applied`. The fingers' two position
actuators (kp 1000, forcerange +-20 N) get position targets.

The policy's observations in robosuite's env (`env.step`'s return) are MuJoCo's data after the
last `mj_step2`: positions computed by `mj_step1` (the grip site's `site_xpos`, the cube's
`body_xpos`) are those of the state one physics step (2 ms) before the returned time, while
`qpos`/`qvel` (the fingers' `robot0_gripper_qpos`) are the state at that time. After a reset,
they are all the reset's (`mj_forward`). robosuite samples its observables on a clock
(`sampling_rate` = control_freq, advanced 2 ms per physics step and by each forced update):
from `env.reset()`, each step's observation is the data after its last physics step, but one
more forced update after the reset moves every later sample a physics step earlier.

Precision: robosuite runs `quat2mat`, `orientation_error`, `opspace_matrices` and
`nullspace_torques` through numba, whose `inv`, `pinv` and `dot` call LAPACK and BLAS
differently from numpy: the controls here differ from robosuite's by 1e-11 N m or less (numpy
1.26 and 2.4 alike). `quat2mat` rounds the rotation to float32 as robosuite's does; in float64
the torques would differ by about 1e-5 N m.

What this does not reproduce: robosuite creates its controllers during its reset, after
setting the arm's joints but before the fingers' and the cube's, and their first update (J, M,
the site's pose) is the one used at the very first physics step of the episode (an update runs
only once per step, `Controller.new_update`). The arm's mass matrix then includes the fingers
where they were before the reset set them (`qpos0` after a hard reset). `reference_runs.py`
recreates the controllers after placing every joint, where the two agree.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import mujoco
import numpy as np

# Lift's names (robosuite's "robot0_" robot, "gripper0_right_" gripper)
ARM_JOINTS = tuple(f"robot0_joint{i}" for i in range(1, 8))
ARM_ACTUATORS = tuple(f"robot0_torq_j{i}" for i in range(1, 8))
GRIPPER_JOINTS = ("gripper0_right_finger_joint1", "gripper0_right_finger_joint2")
GRIPPER_ACTUATORS = (
    "gripper0_right_gripper_finger_joint1",
    "gripper0_right_gripper_finger_joint2",
)
GRIP_SITE = "gripper0_right_grip_site"  # the controlled point (robosuite's eef site)
BASE_SITE = "robot0_right_center"  # the frame of the actions (input_ref_frame "base")

# robosuite's reset (robots/robot.py, Panda's model): arm init_qpos plus a Gaussian draw
INIT_QPOS = np.array(
    [0, np.pi / 16.0, 0.00, -np.pi / 2.0 - np.pi / 3.0, 0.00, np.pi - 0.2, np.pi / 4]
)
INIT_NOISE_STD = 0.02  # rad, standard deviation: initialization_noise "default" (gaussian)
GRIPPER_INIT_QPOS = np.array([0.020833, -0.020833])

# OSC_POSE's defaults (default_panda.json)
INPUT_MAX, INPUT_MIN = np.ones(6), -np.ones(6)
OUTPUT_MAX = np.array([0.05, 0.05, 0.05, 0.5, 0.5, 0.5])  # m and rad per action
OUTPUT_MIN = -OUTPUT_MAX
KP = np.ones(6) * 150
KD = 2 * np.sqrt(KP) * 1  # damping_ratio 1
NULLSPACE_KP = 10  # control_utils.nullspace_torques' joint_kp
# GRIP's defaults; PandaGripper moves its command 0.2 of the way per action
GRIPPER_SPEED = 0.2
GRIPPER_IN_MAX, GRIPPER_IN_MIN = np.ones(2), -np.ones(2)
GRIPPER_OUT_MAX, GRIPPER_OUT_MIN = np.ones(2), -np.ones(2)


@dataclass(frozen=True)
class Ids:
    """Where Lift's arm, fingers and sites sit in a model."""

    arm_qpos: np.ndarray
    arm_dof: np.ndarray
    arm_actuators: np.ndarray
    gripper_actuators: np.ndarray
    grip_site: int
    base_site: int

    @classmethod
    def of(cls, model: mujoco.MjModel) -> Ids:
        def find(kind: mujoco.mjtObj, name: str) -> int:
            i = mujoco.mj_name2id(model, kind, name)
            if i < 0:
                raise ValueError(f"the model has no {kind.name[6:].lower()} named {name!r}")
            return i

        joints = [find(mujoco.mjtObj.mjOBJ_JOINT, n) for n in ARM_JOINTS]
        return cls(
            arm_qpos=np.array([model.jnt_qposadr[j] for j in joints]),
            arm_dof=np.array([model.jnt_dofadr[j] for j in joints]),
            arm_actuators=np.array([find(mujoco.mjtObj.mjOBJ_ACTUATOR, n) for n in ARM_ACTUATORS]),
            gripper_actuators=np.array(
                [find(mujoco.mjtObj.mjOBJ_ACTUATOR, n) for n in GRIPPER_ACTUATORS]
            ),
            grip_site=find(mujoco.mjtObj.mjOBJ_SITE, GRIP_SITE),
            base_site=find(mujoco.mjtObj.mjOBJ_SITE, BASE_SITE),
        )


@dataclass
class State:
    """What robosuite's controllers carry between physics steps of one episode."""

    initial_joint: np.ndarray  # the arm's qpos at reset: the nullspace torques' target
    goal_pos: np.ndarray | None = None  # in the base site's frame, set at each new action
    goal_ori: np.ndarray | None = None  # 3x3, in the base site's frame
    gripper_action: np.ndarray = field(default_factory=lambda: np.zeros(1))  # current_action
    gripper_goal: np.ndarray | None = None  # GRIP's goal_qvel: the fingers' command in [-1, 1]


# --- transform_utils and control_utils, as robosuite writes them ---


def scale_action(action, input_max, input_min, output_max, output_min):
    """Controller.scale_action: clip to the input range, map linearly onto the output range."""
    action_scale = abs(output_max - output_min) / abs(input_max - input_min)
    action_output_transform = (output_max + output_min) / 2.0
    action_input_transform = (input_max + input_min) / 2.0
    action = np.clip(action, input_min, input_max)
    return (action - action_input_transform) * action_scale + action_output_transform


def make_pose(translation, rotation):
    pose = np.zeros((4, 4))
    pose[:3, :3] = rotation
    pose[:3, 3] = translation
    pose[3, 3] = 1.0
    return pose


def pose_inv(pose):
    inv = np.zeros((4, 4))
    inv[:3, :3] = pose[:3, :3].T
    inv[:3, 3] = -inv[:3, :3].dot(pose[:3, 3])
    inv[3, 3] = 1.0
    return inv


def axisangle2quat(vec):
    """An axis-angle vector as a quaternion (x, y, z, w)."""
    angle = np.linalg.norm(vec)
    if math.isclose(angle, 0.0):
        return np.array([0.0, 0.0, 0.0, 1.0])
    axis = vec / angle
    q = np.zeros(4)
    q[3] = np.cos(angle / 2.0)
    q[:3] = axis * np.sin(angle / 2.0)
    return q


def quat2mat(quaternion):
    """A quaternion (x, y, z, w) as a rotation matrix, with robosuite's precision (its numba
    function): the quaternion in float32, scaled in float64 and rounded back, the diagonal's
    sums in float64, the other entries in float32."""
    q = np.asarray(quaternion).copy().astype(np.float32)[np.array([3, 0, 1, 2])]
    n = np.dot(q, q)
    if n < np.finfo(float).eps * 4.0:
        return np.identity(3)
    q = (q.astype(np.float64) * math.sqrt(2.0 / float(n))).astype(np.float32)
    q2 = np.outer(q, q)

    def diagonal(a, b):
        return 1.0 - float(q2[a, a]) - float(q2[b, b])

    return np.array(
        [
            [diagonal(2, 3), q2[1, 2] - q2[3, 0], q2[1, 3] + q2[2, 0]],
            [q2[1, 2] + q2[3, 0], diagonal(1, 3), q2[2, 3] - q2[1, 0]],
            [q2[1, 3] - q2[2, 0], q2[2, 3] + q2[1, 0], diagonal(1, 2)],
        ]
    )


def orientation_error(desired, current):
    """Half the sum of the cross products of the two frames' axes (an axis-angle error)."""
    rc1, rc2, rc3 = current[0:3, 0], current[0:3, 1], current[0:3, 2]
    rd1, rd2, rd3 = desired[0:3, 0], desired[0:3, 1], desired[0:3, 2]
    return 0.5 * (np.cross(rc1, rd1) + np.cross(rc2, rd2) + np.cross(rc3, rd3))


def opspace_matrices(mass_matrix, J_full, J_pos, J_ori):  # noqa: N803 (robosuite's names)
    """The operational-space inertias (full, position, orientation) and the nullspace matrix."""
    mass_matrix_inv = np.linalg.inv(mass_matrix)
    lambda_full_inv = np.dot(np.dot(J_full, mass_matrix_inv), J_full.transpose())
    lambda_pos_inv = np.dot(np.dot(J_pos, mass_matrix_inv), J_pos.transpose())
    lambda_ori_inv = np.dot(np.dot(J_ori, mass_matrix_inv), J_ori.transpose())
    lambda_full = np.linalg.pinv(lambda_full_inv)
    lambda_pos = np.linalg.pinv(lambda_pos_inv)
    lambda_ori = np.linalg.pinv(lambda_ori_inv)
    Jbar = np.dot(mass_matrix_inv, J_full.transpose()).dot(lambda_full)  # noqa: N806
    nullspace_matrix = np.eye(J_full.shape[-1], J_full.shape[-1]) - np.dot(Jbar, J_full)
    return lambda_full, lambda_pos, lambda_ori, nullspace_matrix


def nullspace_torques(mass_matrix, nullspace_matrix, initial_joint, joint_pos, joint_vel):
    """A joint PD toward the reset pose (kp 10, kv 2 sqrt(10)), projected into the nullspace."""
    joint_kv = np.sqrt(NULLSPACE_KP) * 2
    pose_torques = np.dot(
        mass_matrix, (NULLSPACE_KP * (initial_joint - joint_pos) - joint_kv * joint_vel)
    )
    return np.dot(nullspace_matrix.transpose(), pose_torques)


# --- what the controllers read from MuJoCo at each physics step ---


@dataclass
class Reading:
    """Controller.update's quantities, read from `data` after `mj_step1`."""

    origin_pos: np.ndarray
    origin_ori: np.ndarray
    ref_pos: np.ndarray
    ref_ori_mat: np.ndarray
    ref_pos_vel: np.ndarray
    ref_ori_vel: np.ndarray
    base_pos_vel: np.ndarray
    base_ori_vel: np.ndarray
    J_pos: np.ndarray  # noqa: N815
    J_ori: np.ndarray  # noqa: N815
    J_full: np.ndarray  # noqa: N815
    mass_matrix: np.ndarray
    joint_pos: np.ndarray
    joint_vel: np.ndarray
    torque_compensation: np.ndarray


def full_mass_matrix(model: mujoco.MjModel, data: mujoco.MjData) -> np.ndarray:
    """`mj_fullM` (its arguments changed in MuJoCo 3.10: data in place of qM)."""
    dense = np.ndarray(shape=(model.nv, model.nv), dtype=np.float64, order="C")
    try:
        mujoco.mj_fullM(model, data, dense)
    except TypeError:
        mujoco.mj_fullM(model, dense, data.qM)
    return dense


def site_jacobians(model, data, site: int) -> tuple[np.ndarray, np.ndarray]:
    jacp, jacr = np.zeros((3, model.nv)), np.zeros((3, model.nv))
    mujoco.mj_jacSite(model, data, jacp, None, site)
    mujoco.mj_jacSite(model, data, None, jacr, site)
    return jacp, jacr


def read(model: mujoco.MjModel, data: mujoco.MjData, ids: Ids) -> Reading:
    dof = ids.arm_dof
    jacp, jacr = site_jacobians(model, data, ids.grip_site)
    base_jacp, base_jacr = site_jacobians(model, data, ids.base_site)
    J_pos = np.array(jacp.reshape((3, -1))[:, dof])  # noqa: N806
    J_ori = np.array(jacr.reshape((3, -1))[:, dof])  # noqa: N806
    mass_matrix = full_mass_matrix(model, data)
    mass_matrix = np.reshape(mass_matrix, (len(data.qvel), len(data.qvel)))
    return Reading(
        origin_pos=np.array(data.site_xpos[ids.base_site]),
        origin_ori=np.array(data.site_xmat[ids.base_site].reshape([3, 3])),
        ref_pos=np.array(data.site_xpos[ids.grip_site]),
        ref_ori_mat=np.array(data.site_xmat[ids.grip_site].reshape([3, 3])),
        ref_pos_vel=np.array(np.dot(jacp, data.qvel)),
        ref_ori_vel=np.array(np.dot(jacr, data.qvel)),
        base_pos_vel=np.array(np.dot(base_jacp, data.qvel)),
        base_ori_vel=np.array(np.dot(base_jacr, data.qvel)),
        J_pos=J_pos,
        J_ori=J_ori,
        J_full=np.vstack([J_pos, J_ori]),
        mass_matrix=mass_matrix[dof, :][:, dof],
        joint_pos=np.array(data.qpos[ids.arm_qpos]),
        joint_vel=np.array(data.qvel[dof]),
        torque_compensation=data.qfrc_bias[dof],
    )


# --- OSC_POSE ---


def set_arm_goal(state: State, r: Reading, delta_action: np.ndarray) -> None:
    """OperationalSpaceController.set_goal with a delta action, "achieved" mode, base frame."""
    scaled_delta = scale_action(delta_action, INPUT_MAX, INPUT_MIN, OUTPUT_MAX, OUTPUT_MIN)
    origin_inv = pose_inv(make_pose(r.origin_pos, r.origin_ori))
    world_frame = np.eye(4)
    world_frame[:3, 3] = r.ref_pos
    state.goal_pos = origin_inv.dot(world_frame)[:3, 3] + scaled_delta[0:3]
    curr_goal_ori = origin_inv.dot(make_pose(r.ref_pos, r.ref_ori_mat))[:3, :3]
    rotation_mat_error = quat2mat(axisangle2quat(scaled_delta[3:6]))
    state.goal_ori = np.dot(rotation_mat_error, curr_goal_ori)


def arm_torques(state: State, r: Reading) -> np.ndarray:
    """OperationalSpaceController.run_controller: the arm's joint torques, before clipping."""
    desired_world_pos = r.origin_pos + np.dot(r.origin_ori, state.goal_pos)
    desired_world_ori = np.dot(r.origin_ori, state.goal_ori)
    ori_error = orientation_error(desired_world_ori, r.ref_ori_mat)
    position_error = desired_world_pos - r.ref_pos
    vel_pos_error = -(r.ref_pos_vel - r.base_pos_vel)
    desired_force = np.multiply(np.array(position_error), np.array(KP[0:3])) + np.multiply(
        vel_pos_error, KD[0:3]
    )
    vel_ori_error = -(r.ref_ori_vel - r.base_ori_vel)
    desired_torque = np.multiply(np.array(ori_error), np.array(KP[3:6])) + np.multiply(
        vel_ori_error, KD[3:6]
    )
    _, lambda_pos, lambda_ori, nullspace_matrix = opspace_matrices(
        r.mass_matrix, r.J_full, r.J_pos, r.J_ori
    )
    decoupled_force = np.dot(lambda_pos, desired_force)  # uncouple_pos_ori: true
    decoupled_torque = np.dot(lambda_ori, desired_torque)
    decoupled_wrench = np.concatenate([decoupled_force, decoupled_torque])
    torques = np.dot(r.J_full.T, decoupled_wrench) + r.torque_compensation
    torques += nullspace_torques(
        r.mass_matrix, nullspace_matrix, state.initial_joint, r.joint_pos, r.joint_vel
    )
    return torques


# --- the gripper (PandaGripper.format_action, then GRIP) ---


def set_gripper_goal(state: State, command: np.ndarray) -> None:
    """The gripper's command moves 0.2 toward closed (+1) or open (-1) per action, by its
    sign only; GRIP then keeps it as its goal."""
    state.gripper_action = np.clip(
        state.gripper_action + np.array([-1.0, 1.0]) * GRIPPER_SPEED * np.sign(command),
        -1.0,
        1.0,
    )
    state.gripper_goal = scale_action(
        state.gripper_action, GRIPPER_IN_MAX, GRIPPER_IN_MIN, GRIPPER_OUT_MAX, GRIPPER_OUT_MIN
    )


def gripper_targets(model: mujoco.MjModel, ids: Ids, goal: np.ndarray) -> np.ndarray:
    """SimpleGripController.run_controller: the command in [-1, 1] mapped onto each finger
    actuator's control range."""
    ctrl_range = model.actuator_ctrlrange[ids.gripper_actuators]
    bias = 0.5 * (ctrl_range[:, 1] + ctrl_range[:, 0])
    weight = 0.5 * (ctrl_range[:, 1] - ctrl_range[:, 0])
    return bias + weight * goal


# --- one physics step ---


def start(model: mujoco.MjModel, data: mujoco.MjData, ids: Ids | None = None) -> State:
    """The controllers' state at an episode's start: `data` holds the reset state."""
    ids = ids or Ids.of(model)
    return State(initial_joint=np.array(data.qpos[ids.arm_qpos]))


def ctrl(
    model: mujoco.MjModel,
    data: mujoco.MjData,
    ids: Ids,
    state: State,
    action: np.ndarray,
    new_action: bool,
) -> np.ndarray:
    """The controls robosuite writes at this physics step (`data` after `mj_step1`), for
    every actuator of Lift (the arm's 7, then the fingers' 2, in the model's order).

    `action` is the policy's latest 7-vector; `new_action` is True at the first physics step
    after it arrived, where the goals are set. `state` is updated in place."""
    action = np.asarray(action, dtype=np.float64)
    if action.shape != (7,):
        raise ValueError(f"a Lift action has 7 numbers, got shape {action.shape}")
    r = read(model, data, ids)
    if new_action:
        set_arm_goal(state, r, action[0:6])
        set_gripper_goal(state, action[6:7])
    if state.goal_pos is None or state.gripper_goal is None:
        raise ValueError("the first physics step of an episode needs new_action=True")
    out = np.array(data.ctrl)
    low, high = model.actuator_ctrlrange.T
    arm, grip = ids.arm_actuators, ids.gripper_actuators
    out[arm] = np.clip(arm_torques(state, r), low[arm], high[arm])
    out[grip] = np.clip(gripper_targets(model, ids, state.gripper_goal), low[grip], high[grip])
    return out


def episode(
    model: mujoco.MjModel,
    data: mujoco.MjData,
    actions: np.ndarray,
    steps_per_action: int = 25,
    on_step=None,
) -> State:
    """The plain loop: each action held for `steps_per_action` physics steps of
    `mj_step1`, `ctrl`, `mj_step2`, from the reset state in `data`. `on_step(data)`, if given,
    is called at each physics step between the controls and `mj_step2` (`data` then holds
    `mj_step1`'s quantities and the controls)."""
    ids = Ids.of(model)
    state = start(model, data, ids)
    for action in actions:
        for i in range(steps_per_action):
            mujoco.mj_step1(model, data)
            data.ctrl[:] = ctrl(model, data, ids, state, action, new_action=(i == 0))
            if on_step is not None:
                on_step(data)
            mujoco.mj_step2(model, data)
    return state
