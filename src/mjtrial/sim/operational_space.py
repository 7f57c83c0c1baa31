"""robosuite's arm and hand controllers as a low-level controller (`mjtrial.sim.low_level`), on a
batch of episodes at once.

robosuite 1.5.2's default arm controller is OSC_POSE (`controllers/parts/arm/osc.py`,
`utils/control_utils.py`), its default hand controller GRIP (`simple_grip.py`), with the
defaults of `controllers/config/robots/default_panda.json`. Its
`env.step` runs, at every 2 ms physics step of a 50 ms action (`lite_physics`, the default):
`mj_step1`, the robot's `control` (the goals set from the action at the first step of the
action, the torques from the state at every step), `mj_step2`. This module is that arithmetic,
operation for operation, on stacks of matrices (row i: episode i), so that the whole batch costs
a few numpy calls per physics step instead of a few dozen per episode:

- the goal, at each new action (`set_goal`, input frame "base", goal from the achieved pose):
  the action clipped to [-1, 1] and scaled to `output_max` (5 cm, 0.5 rad); the position goal
  the grip site's position in the base frame plus the delta; the orientation goal the delta's
  rotation (robosuite's `axisangle2quat` then `quat2mat`, which rounds the quaternion to float32)
  times the site's orientation in the base frame;
- the torques, at every step (`run_controller`): the pose error (position, and robosuite's
  `orientation_error`) times kp, minus the site's velocity (its Jacobian times qvel) times
  kd = 2 sqrt(kp) damping_ratio; each mapped through its own operational-space inertia
  (`pinv(J M^-1 J^T)`, position and orientation uncoupled), through J^T, plus `qfrc_bias`, plus
  the null-space torques pulling the joints toward their pose at the episode's start
  (kp 10, critically damped); clipped to the actuators' ctrlrange;
- the hand (the Panda hand's `format_action`, then GRIP): at each action its command moves by
  0.2 toward the action's sign, clipped to [-1, 1], for its two actuators as [-c, c]; the two
  position actuators get the middle of their ctrlrange plus c times its half width.

The batched products and inverses are numpy's stacked `matmul` and `inv`, which treat each
matrix of a stack alone: a row's result does not depend on the rows beside it (the config check
runs a batch and each row alone: `low_level.check_rows_alone`). robosuite inverts the
operational-space inertias with `np.linalg.pinv` (an SVD, about 150 µs a matrix here, more than
the physics step); for an invertible matrix that is its inverse, to rounding, and here they are
inverted together in one `inv` call: the two differ only at a singular arm configuration, where
`pinv` drops the singular directions. The position's and the orientation's inertias are the
diagonal blocks of the full one, as robosuite computes them.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import mujoco
import numpy as np

from mjtrial.sim.low_level import PhysicsView, Reads, jacobian_is_zero

NULLSPACE_KP = 10.0  # robosuite's `nullspace_torques` default joint_kp
GRIPPER_SPEED = 0.2  # robosuite's PandaGripper.speed: command change per action


@dataclass(frozen=True)
class OscSettings:
    """OSC_POSE's settings, robosuite's defaults (`default_panda.json`)."""

    kp: float = 150.0
    damping_ratio: float = 1.0
    output_max: tuple[float, ...] = (0.05, 0.05, 0.05, 0.5, 0.5, 0.5)
    input_max: float = 1.0


def _ids(model: mujoco.MjModel, kind: mujoco.mjtObj, names: Sequence[str]) -> np.ndarray:
    ids = [mujoco.mj_name2id(model, kind, n) for n in names]
    missing = [n for n, i in zip(names, ids, strict=True) if i < 0]
    if missing:
        raise ValueError(
            f"OperationalSpace: no {kind.name[6:].lower()} {missing[0]!r} in the model"
        )
    return np.array(ids)


def orientation_error(desired: np.ndarray, current: np.ndarray) -> np.ndarray:
    """robosuite's `orientation_error` on stacks (n, 3, 3) of rotation matrices: half the sum
    of the cross products of the current and the desired frames' columns, sum_m c_m x d_m,
    whose components are the antisymmetric part of P = C D^T (one product for the stack).
    `OperationalSpace` computes the same into its buffers."""
    p = current @ np.swapaxes(desired, 1, 2)
    return 0.5 * np.stack(
        [p[:, 1, 2] - p[:, 2, 1], p[:, 2, 0] - p[:, 0, 2], p[:, 0, 1] - p[:, 1, 0]], axis=1
    )


def rotation_of_axis_angle(vec: np.ndarray) -> np.ndarray:
    """(n, 3) scaled axis-angles -> (n, 3, 3) rotation matrices as robosuite computes them:
    `axisangle2quat` in float64, then `quat2mat` (compiled by numba), which rounds the
    quaternion to float32, scales it in float64, and forms the diagonal in float64 and the
    off-diagonal terms in float32."""
    angle = np.linalg.norm(vec, axis=1)
    zero = np.abs(angle) <= 1e-9 * np.abs(angle)  # math.isclose(angle, 0.0): angle == 0
    safe = np.where(zero, 1.0, angle)
    q = np.zeros((len(vec), 4))  # w, x, y, z: quat2mat's own order
    q[:, 0] = np.where(zero, 1.0, np.cos(angle / 2.0))
    q[:, 1:] = np.where(zero[:, None], 0.0, (vec / safe[:, None]) * np.sin(angle / 2.0)[:, None])
    q = q.astype(np.float32)
    n = ((q[:, 0] * q[:, 0] + q[:, 1] * q[:, 1]) + q[:, 2] * q[:, 2]) + q[:, 3] * q[:, 3]
    q = (q.astype(np.float64) * np.sqrt(2.0 / n.astype(np.float64))[:, None]).astype(np.float32)
    q2 = q[:, :, None] * q[:, None, :]  # float32
    d = q2.astype(np.float64)

    def off(a: np.ndarray) -> np.ndarray:  # a float32 sum, then widened
        return a.astype(np.float64)

    rows = [
        [
            1.0 - d[:, 2, 2] - d[:, 3, 3],
            off(q2[:, 1, 2] - q2[:, 3, 0]),
            off(q2[:, 1, 3] + q2[:, 2, 0]),
        ],
        [
            off(q2[:, 1, 2] + q2[:, 3, 0]),
            1.0 - d[:, 1, 1] - d[:, 3, 3],
            off(q2[:, 2, 3] - q2[:, 1, 0]),
        ],
        [
            off(q2[:, 1, 3] - q2[:, 2, 0]),
            off(q2[:, 2, 3] + q2[:, 1, 0]),
            1.0 - d[:, 1, 1] - d[:, 2, 2],
        ],
    ]
    return np.stack([np.stack(r, axis=1) for r in rows], axis=1)


class _Buffers:
    """Preallocated arrays for a batch of n rows: every product, inverse input and difference
    of a physics step is written with `out=` into one of these, in the layout (contiguous,
    or the same transposed view) the allocating expression gave it, so each stacked
    `matmul` makes the same BLAS call on the same numbers and the results stay bit for bit
    those of the plain expressions; about half the controller's cost was allocation and
    wrapper calls."""

    def __init__(self, n: int, k: int, nu: int) -> None:
        self.site_vel = np.zeros((n, 6, 1))  # the grip site's velocity, position then rotation
        self.base_vel = np.zeros((n, 6, 1))  # the base site's
        self.damping = np.zeros((n, 6, 1))
        self.wrench_in = np.zeros((n, 6, 1))  # the pose error times kp, damping added
        self.ori_product = np.zeros((n, 3, 3))
        self.j_full = np.zeros((n, 6, k))
        self.j_full_t = np.swapaxes(self.j_full, 1, 2)
        self.m_inv_jt = np.zeros((n, k, 6))
        self.blocks = np.zeros((n, 2, 6, 6))  # the full inertia and its two diagonal blocks
        self.m_inv_jt_lambda = np.zeros((n, k, 6))
        self.projection = np.zeros((n, k, k))
        self.nullspace = np.zeros((n, k, k))
        self.nullspace_t = np.swapaxes(self.nullspace, 1, 2)
        self.wrench = np.zeros((n, 6, 1))
        self.task_torques = np.zeros((n, k, 1))
        self.posture = np.zeros((n, k))
        self.damped = np.zeros((n, k))
        self.posture_force = np.zeros((n, k, 1))
        self.posture_torques = np.zeros((n, k, 1))
        self.raw = np.zeros((n, nu))  # the controls before clipping; the hand's set per action
        # the desired pose in the world, set from the goal and the base's pose; reused while
        # the base's pose is the same, bit for bit (a fixed base: every step of an action)
        self.desired_pos = np.zeros((n, 3))
        self.desired_ori = np.zeros((n, 3, 3))
        self.desired_ori_t = np.swapaxes(self.desired_ori, 1, 2)
        self.desired_from: tuple[bytes, bytes] | None = None


class OperationalSpace:
    """robosuite's OSC_POSE arm controller and GRIP hand controller on a batch of episodes
    (the module's docstring says what is computed and when).

    The action has 7 columns: the grip site's position change (3) and rotation (3, axis-angle)
    in [-1, 1] of `output_max`, in the robot base's frame, and the hand's command (> 0 closes).

    Args:
      model: the nominal model (element ids; each episode's ranges are read at `reset`).
      site: the grip site the pose is controlled at (robosuite's `gripper0_right_grip_site`).
      base_site: the site whose frame is the action's (`robot0_right_center`).
      arm_actuators: the arm's torque actuators, one per joint, in the joints' order.
      hand_actuators: the hand's two actuators (position servos), in robosuite's order.
      settings: OSC_POSE's gains and scales (robosuite's defaults).
    """

    n_inputs = 7

    def __init__(
        self,
        model: mujoco.MjModel,
        *,
        site: str,
        base_site: str,
        arm_actuators: Sequence[str],
        hand_actuators: Sequence[str],
        settings: OscSettings = OscSettings(),
    ) -> None:
        self.reads = Reads(sites=(site, base_site), mass_matrix=True, bias=True)
        self.base_site = _ids(model, mujoco.mjtObj.mjOBJ_SITE, [base_site])[0]
        self.arm = _ids(model, mujoco.mjtObj.mjOBJ_ACTUATOR, arm_actuators)
        self.hand = _ids(model, mujoco.mjtObj.mjOBJ_ACTUATOR, hand_actuators)
        if set(self.arm) & set(self.hand):
            raise ValueError("OperationalSpace: an actuator is both the arm's and the hand's")
        joints = model.actuator_trnid[self.arm, 0]
        self.qpos = model.jnt_qposadr[joints]
        self.dofs = model.jnt_dofadr[joints]
        # the arm's dofs, qpos and actuators as slices where they are contiguous (views)
        self.dof_block = _block(self.dofs)
        self.qpos_block = _block(self.qpos)
        self.arm_block = _block(self.arm)
        self.eye = np.eye(len(joints))
        self.nu = model.nu
        self.kp = np.full(6, settings.kp)
        self.kd = 2 * np.sqrt(self.kp) * settings.damping_ratio
        self.kp_column, self.kd_column = self.kp[:, None], self.kd[:, None]
        self.posture_kv = np.sqrt(NULLSPACE_KP) * 2
        output_max = np.asarray(settings.output_max)
        # robosuite's scale_action: |out_max - out_min| / |in_max - in_min|, both symmetric
        self.action_scale = np.abs(output_max - -output_max) / abs(
            settings.input_max - -settings.input_max
        )
        self.input_max = settings.input_max

    def reset(self, models: Sequence[mujoco.MjModel]) -> None:
        n = len(models)
        self.arm_low = np.stack([m.actuator_ctrlrange[self.arm, 0] for m in models])
        self.arm_high = np.stack([m.actuator_ctrlrange[self.arm, 1] for m in models])
        grip = np.stack([m.actuator_ctrlrange[self.hand] for m in models])  # (n, 2, 2)
        self.grip_low, self.grip_high = grip[:, :, 0], grip[:, :, 1]
        self.grip_bias = 0.5 * (grip[:, :, 1] + grip[:, :, 0])
        self.grip_weight = 0.5 * (grip[:, :, 1] - grip[:, :, 0])
        # the controls' bounds, the arm's and the hand's ranges (the others unbounded: zero)
        self.ctrl_low = np.full((n, self.nu), -np.inf)
        self.ctrl_high = np.full((n, self.nu), np.inf)
        self.ctrl_low[:, self.arm], self.ctrl_high[:, self.arm] = self.arm_low, self.arm_high
        self.ctrl_low[:, self.hand], self.ctrl_high[:, self.hand] = self.grip_low, self.grip_high
        # a base on no joint (robosuite's: a fixed robot) has a zero Jacobian, so its velocity,
        # a matrix product with it, is +0.0, which leaves the site's velocity as it is
        self.base_moves = not all(
            jacobian_is_zero(m, m.site_bodyid[self.base_site]) for m in models
        )
        self.initial_joint: np.ndarray | None = None  # the arm's pose at the first step
        self.goal_pos = np.zeros((n, 3))
        self.goal_ori = np.zeros((n, 3, 3))
        self.grip_command = np.zeros((n, 2))
        self.buffers = _Buffers(n, len(self.dofs), self.nu)
        self.buffers.raw[:, self.hand] = self.grip_bias + self.grip_weight * self.grip_command

    def __call__(self, view: PhysicsView, action: np.ndarray, new_action: bool) -> np.ndarray:
        n = len(view.qpos)
        b, dofs = self.buffers, self.dof_block
        joint_pos, joint_vel = view.qpos[:, self.qpos_block], view.qvel[:, dofs]
        if self.initial_joint is None:
            self.initial_joint = joint_pos.copy()
        ref_pos = view.site_xpos[:, 0]
        ref_ori = view.site_xmat[:, 0].reshape(n, 3, 3)
        origin_pos = view.site_xpos[:, 1]
        origin_ori = view.site_xmat[:, 1].reshape(n, 3, 3)
        jacp, jacr = view.site_jacp[:, 0], view.site_jacr[:, 0]  # (n, 3, nv)
        qvel = view.qvel[:, :, None]
        np.matmul(jacp, qvel, out=b.site_vel[:, :3])
        np.matmul(jacr, qvel, out=b.site_vel[:, 3:])
        if self.base_moves:
            np.matmul(view.site_jacp[:, 1], qvel, out=b.base_vel[:, :3])
            np.matmul(view.site_jacr[:, 1], qvel, out=b.base_vel[:, 3:])
            np.subtract(b.site_vel, b.base_vel, out=b.damping)
            np.negative(b.damping, out=b.damping)
        else:
            np.negative(b.site_vel, out=b.damping)
        if new_action:
            self._set_goal(b, action, ref_pos, ref_ori, origin_pos, origin_ori)
        base_pose = (origin_pos.tobytes(), origin_ori.tobytes())
        if base_pose != b.desired_from:
            b.desired_pos[...] = origin_pos + (origin_ori @ self.goal_pos[:, :, None])[:, :, 0]
            np.matmul(origin_ori, self.goal_ori, out=b.desired_ori)
            b.desired_from = base_pose
        # the pose error (robosuite's orientation_error: the antisymmetric part of
        # current @ desired^T) times kp, and the damping, -(site - base velocity) kd
        error = b.wrench_in[:, :, 0]
        np.subtract(b.desired_pos, ref_pos, out=error[:, :3])
        p = np.matmul(ref_ori, b.desired_ori_t, out=b.ori_product)
        np.subtract(p[:, 1, 2], p[:, 2, 1], out=error[:, 3])
        np.subtract(p[:, 2, 0], p[:, 0, 2], out=error[:, 4])
        np.subtract(p[:, 0, 1], p[:, 1, 0], out=error[:, 5])
        np.multiply(error[:, 3:], 0.5, out=error[:, 3:])
        np.multiply(b.wrench_in, self.kp_column, out=b.wrench_in)
        np.multiply(b.damping, self.kd_column, out=b.damping)
        np.add(b.wrench_in, b.damping, out=b.wrench_in)
        # the operational-space inertias and the null space, as robosuite computes them
        mass = view.mass_matrix[:, dofs, dofs]
        b.j_full[:, :3] = jacp[:, :, dofs]
        b.j_full[:, 3:] = jacr[:, :, dofs]
        mass_inv = np.linalg.inv(mass)
        np.matmul(mass_inv, b.j_full_t, out=b.m_inv_jt)
        # J M^-1 J^T: its 3x3 diagonal blocks are the position's and the orientation's own;
        # all three inverted in one call, the blocks side by side
        inertia_inv = np.matmul(b.j_full, b.m_inv_jt, out=b.blocks[:, 0])
        b.blocks[:, 1, :3, :3] = inertia_inv[:, :3, :3]
        b.blocks[:, 1, 3:, 3:] = inertia_inv[:, 3:, 3:]
        inverses = np.linalg.inv(b.blocks)
        lambda_full, lambda_split = inverses[:, 0], inverses[:, 1]
        np.matmul(b.m_inv_jt, lambda_full, out=b.m_inv_jt_lambda)
        np.matmul(b.m_inv_jt_lambda, b.j_full, out=b.projection)
        np.subtract(self.eye, b.projection, out=b.nullspace)
        np.matmul(lambda_split, b.wrench_in, out=b.wrench)
        np.matmul(b.j_full_t, b.wrench, out=b.task_torques)
        torques = b.raw[:, self.arm_block]
        np.add(b.task_torques[:, :, 0], view.bias[:, dofs], out=torques)
        # the null-space torques toward the first step's pose (kp 10, critically damped)
        posture = b.posture
        np.subtract(self.initial_joint, joint_pos, out=posture)
        np.multiply(NULLSPACE_KP, posture, out=posture)
        np.multiply(self.posture_kv, joint_vel, out=b.damped)
        np.subtract(posture, b.damped, out=posture)
        np.matmul(mass, posture[:, :, None], out=b.posture_force)
        np.matmul(b.nullspace_t, b.posture_force, out=b.posture_torques)
        torques += b.posture_torques[:, :, 0]
        if not isinstance(self.arm_block, slice):
            b.raw[:, self.arm] = torques
        return b.raw.clip(self.ctrl_low, self.ctrl_high)  # np.clip's own ufunc, fewer layers

    def _set_goal(self, b: _Buffers, action, ref_pos, ref_ori, origin_pos, origin_ori) -> None:
        """robosuite's `set_goal` at a new action: the pose goal in the base frame, the hand's
        command and its control."""
        origin_t = np.swapaxes(origin_ori, 1, 2)
        delta = (np.clip(action[:, :6], -self.input_max, self.input_max) - 0.0) * (
            self.action_scale
        ) + 0.0
        # the achieved pose in the base frame (robosuite's pose_inv and 4x4 products)
        origin_inv_pos = -(origin_t @ origin_pos[:, :, None])[:, :, 0]
        self.goal_pos = (origin_t @ ref_pos[:, :, None])[:, :, 0] + origin_inv_pos + delta[:, :3]
        self.goal_ori = rotation_of_axis_angle(delta[:, 3:6]) @ (origin_t @ ref_ori)
        self.grip_command = np.clip(
            self.grip_command + np.array([-1.0, 1.0]) * GRIPPER_SPEED * np.sign(action[:, 6:7]),
            -1.0,
            1.0,
        )
        b.raw[:, self.hand] = self.grip_bias + self.grip_weight * self.grip_command
        b.desired_from = None


def _block(ids: np.ndarray) -> slice | np.ndarray:
    """Consecutive ids as a slice (indexing by it is a view, not a copy), else the ids."""
    first = int(ids[0])
    if np.array_equal(ids, np.arange(first, first + len(ids))):
        return slice(first, first + len(ids))
    return ids
