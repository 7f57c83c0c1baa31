"""Controllers a task can use: LQR gains from MuJoCo's own linearization, a linear feedback
policy on encoder readings with velocities by finite differences, and low-level controllers run
at every physics step (`mjtrial.sim.low_level`): joint impedance with gravity compensation.

The gains come from `mujoco.mjd_transitionFD` (the discrete-time transition Jacobians of the
model at an operating point) and scipy's discrete algebraic Riccati solver, so the controller is
designed on exactly the dynamics the experiment simulates, integrator and timestep included.
"""

from __future__ import annotations

from collections.abc import Sequence

import mujoco
import numpy as np
import scipy.linalg

from mjtrial.sim.low_level import PhysicsView, Reads


def lqr_gain(
    model: mujoco.MjModel,
    *,
    q: np.ndarray,
    r: np.ndarray,
    steps_per_control: int = 1,
    qpos: np.ndarray | None = None,
    eps: float = 1e-6,
) -> np.ndarray:
    """The discrete LQR gain K (u = -K x, x = [qpos, qvel]) about an operating point.

    The model is linearized over one physics step (A, B from `mjd_transitionFD`, centred
    differences), then held over `steps_per_control` steps (A^s, sum of A^i B): a zero-order
    hold at the control rate, as the engine applies controls.

    Args:
      model: the nominal model (it must have no activations: x is [qpos, qvel]).
      q: (2 nv, 2 nv) state cost; r: (nu, nu) control cost.
      steps_per_control: physics steps per control period.
      qpos: the operating point's positions (default: the model's qpos0), at rest, zero control.
    Returns:
      (nu, 2 nv) gain matrix.
    """
    if model.na:
        raise ValueError("lqr_gain: models with actuator activations are not supported")
    data = mujoco.MjData(model)
    if qpos is not None:
        data.qpos[:] = qpos
    mujoco.mj_forward(model, data)
    nx = 2 * model.nv
    a = np.zeros((nx, nx))
    b = np.zeros((nx, model.nu))
    mujoco.mjd_transitionFD(model, data, eps, True, a, b, None, None)
    a_hold, b_hold = np.eye(nx), np.zeros_like(b)
    for _ in range(steps_per_control):
        a_hold, b_hold = a @ a_hold, a @ b_hold + b
    p = scipy.linalg.solve_discrete_are(a_hold, b_hold, q, r)
    return np.linalg.solve(r + b_hold.T @ p @ b_hold, b_hold.T @ p @ a_hold)


class EncoderFeedback:
    """u = -K [y, (y - y_prev) / period], clipped to the actuators' range: linear feedback on
    encoder readings y, velocities by finite differences between control instants (zero at the
    first instant).

    Each row is computed from that row alone with elementwise arithmetic in a fixed order, so an
    episode's controls do not depend on its batch (a matrix product's summation order may).
    """

    def __init__(self, gain: np.ndarray, *, period: float, ctrl_range: np.ndarray) -> None:
        self.gain = np.asarray(gain, dtype=np.float64)  # (nu, 2 ny)
        self.period = float(period)
        self.low, self.high = np.asarray(ctrl_range, dtype=np.float64).T
        self._previous: np.ndarray | None = None

    def reset(self, n_episodes: int) -> None:
        self._previous = None

    def __call__(self, observations: np.ndarray) -> np.ndarray:
        y = np.asarray(observations, dtype=np.float64)
        previous = y if self._previous is None else self._previous
        self._previous = y.copy()
        velocity = (y - previous) / self.period
        return self._controls(y, velocity)

    def _controls(self, y: np.ndarray, velocity: np.ndarray) -> np.ndarray:
        state = np.concatenate([y, velocity], axis=1)
        u = np.zeros((len(y), len(self.gain)))
        for j in range(state.shape[1]):  # fixed order: the same sum for any batch
            u -= self.gain[:, j][None, :] * state[:, j][:, None]
        return np.clip(u, self.low, self.high)

    def alone(self, observations: np.ndarray) -> np.ndarray:
        """One episode's controls from a reset, (k, n_observations) -> (k, nu): what a reset and
        a call per instant give, bit for bit (the same elementwise arithmetic, its previous
        readings shifted by one), in one pass: the replay check's
        (`closed_loop.check_replayed`), which otherwise costs a call per instant and episode."""
        y = np.asarray(observations, dtype=np.float64)
        previous = np.concatenate([y[:1], y[:-1]])
        return self._controls(y, (y - previous) / self.period)


class StateFeedback:
    """u = -K y on observations y read as they are (no memory), clipped to the actuators'
    range: the textbook state feedback, which needs the velocities observed directly, and so
    a privileged observation unless a sensor measures them. Elementwise, in a fixed order, like
    `EncoderFeedback`, so an episode's controls do not depend on its batch."""

    def __init__(self, gain: np.ndarray, *, ctrl_range: np.ndarray) -> None:
        self.gain = np.asarray(gain, dtype=np.float64)  # (nu, ny)
        self.low, self.high = np.asarray(ctrl_range, dtype=np.float64).T

    def reset(self, n_episodes: int) -> None:
        pass

    def __call__(self, observations: np.ndarray) -> np.ndarray:
        y = np.asarray(observations, dtype=np.float64)
        u = np.zeros((len(y), len(self.gain)))
        for j in range(y.shape[1]):
            u -= self.gain[:, j][None, :] * y[:, j][:, None]
        return np.clip(u, self.low, self.high)

    def alone(self, observations: np.ndarray) -> np.ndarray:
        """One episode's controls at each of its instants (no memory: its rows as a batch), for
        the replay check (see `EncoderFeedback.alone`)."""
        return self(observations)


class JointImpedance:
    """A low-level controller (`mjtrial.sim.low_level`): joint-space impedance with gravity and
    Coriolis compensation, at every physics step,
    tau = kp (q_goal - q) - kd qdot + qfrc_bias, ctrl = tau / gear clipped to the ctrlrange.

    The action is a change of the arm's joint goals (`scale` radians per unit), applied once
    when it arrives, from the joints' positions then (robosuite's JOINT_POSITION controller,
    delta input, goal from the achieved position). Elementwise arithmetic, row by row, so an
    episode's controls do not depend on its batch.

    Args:
      model: the nominal model (element ids; each episode's own ranges and gears are read at
        `reset`).
      actuators: the arm's actuators, each a motor on one hinge or slide joint.
      kp: stiffness (N m / rad), kd: damping (N m s / rad), per actuator or one for all.
      scale: goal change per unit of action.
    """

    reads = Reads(bias=True)

    def __init__(
        self,
        model: mujoco.MjModel,
        actuators: Sequence[str],
        *,
        kp: float | Sequence[float],
        kd: float | Sequence[float],
        scale: float,
    ) -> None:
        ids = [mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_ACTUATOR, a) for a in actuators]
        for name, i in zip(actuators, ids, strict=True):
            if i < 0 or model.actuator_trntype[i] != mujoco.mjtTrn.mjTRN_JOINT:
                raise ValueError(f"JointImpedance: actuator {name!r}: expected one on a joint")
        self.actuators = np.array(ids)
        joints = model.actuator_trnid[self.actuators, 0]
        self.qpos = model.jnt_qposadr[joints]
        self.dofs = model.jnt_dofadr[joints]
        self.kp = np.broadcast_to(np.asarray(kp, dtype=np.float64), len(ids)).copy()
        self.kd = np.broadcast_to(np.asarray(kd, dtype=np.float64), len(ids)).copy()
        self.scale = float(scale)
        self.n_inputs = len(ids)
        self.nu = model.nu

    def reset(self, models) -> None:
        a = self.actuators
        self.gear = np.stack([m.actuator_gear[a, 0] for m in models])
        self.low = np.stack([m.actuator_ctrlrange[a, 0] for m in models])
        self.high = np.stack([m.actuator_ctrlrange[a, 1] for m in models])
        self.goal = np.zeros((len(models), len(a)))

    def __call__(self, view: PhysicsView, action: np.ndarray, new_action: bool) -> np.ndarray:
        q, qdot = view.qpos[:, self.qpos], view.qvel[:, self.dofs]
        if new_action:
            self.goal = q + self.scale * action
        tau = self.kp * (self.goal - q) - self.kd * qdot + view.bias[:, self.dofs]
        ctrl = np.zeros((len(q), self.nu))
        ctrl[:, self.actuators] = np.clip(tau / self.gear, self.low, self.high)
        return ctrl
