"""What a closed-loop policy's output columns drive, bound to a model: actuators' ctrl and mocap
bodies' target poses (`mjtrial.task.Control`, `mjtrial.task.MocapAction` declare them).

Benchmark suites move an arm through a mocap body welded to its hand: every control step the
mocap target is moved (by a position delta from the hand's pose in gymnasium-robotics' Fetch,
from the previous target and clipped to a box in Metaworld) and the equality constraint pulls
the hand after it. `mujoco.rollout` takes the mocap poses as controls (`MOCAP_SPEC` beside the
ctrl and the applied wrenches), so the lockstep engine runs such a policy as any other. The
target chosen at a control instant holds for the physics steps up to the next one.
"""

from __future__ import annotations

from dataclasses import dataclass

import mujoco
import numpy as np

from mjtrial.sim.physics import FULLPHYSICS, STATE_QPOS

# The mocap bodies' target poses as rollout controls, after the ctrl and the applied wrenches.
MOCAP_SPEC = mujoco.mjtState.mjSTATE_MOCAP_POS.value | mujoco.mjtState.mjSTATE_MOCAP_QUAT.value
RELATIVE_TO = ("absolute", "target", "body")


@dataclass(frozen=True)
class ControlColumn:
    """One output column driving one or more actuators: ctrl = sign * scale * value (+ the
    joint position of each actuator's joint, `qpos` addresses, when relative)."""

    column: int
    actuators: np.ndarray  # (k,) actuator indices
    qpos: np.ndarray | None  # (k,) qpos address of each actuator's joint, or None (absolute)
    scale: float
    signs: tuple[int, ...] = ()  # (k,) +1 or -1 per actuator (a hand's [a, -a]); (): all +1

    def sign(self, j: int) -> int:
        """The sign of the column's j-th actuator."""
        return self.signs[j] if self.signs else 1


@dataclass(frozen=True)
class MocapColumns:
    """Three output columns moving one mocap body's target position (see `MocapAction`)."""

    column: int  # the first of three
    mocap: int  # index among the model's mocap bodies
    relative_to: str  # one of RELATIVE_TO
    welded: int  # the body welded to the mocap body (its pose is the reference of "body")
    scale: float
    max_step: float | None
    low: np.ndarray | None  # (3,) the box the target is clipped to, or None
    high: np.ndarray | None
    orientation: np.ndarray | None  # (4,) a fixed target orientation (w, x, y, z)
    orientation_offset: np.ndarray | None  # (4,) added to the reference's quaternion


@dataclass(frozen=True)
class Actuation:
    """A policy's output columns bound to a model.

    `passthrough` (no actions declared): the outputs are every actuator's ctrl, in order.
    Otherwise an actuator no column drives gets ctrl 0, and a mocap body no column moves keeps
    its target from the episode's start.
    """

    nu: int
    nmocap: int
    n_outputs: int
    controls: tuple[ControlColumn, ...] = ()
    mocaps: tuple[MocapColumns, ...] = ()

    @classmethod
    def every_actuator(cls, model: mujoco.MjModel) -> Actuation:
        return cls(model.nu, model.nmocap, model.nu)

    @property
    def passthrough(self) -> bool:
        return not self.controls and not self.mocaps

    @property
    def moves_mocap(self) -> bool:
        return bool(self.mocaps)

    @property
    def welded_bodies(self) -> tuple[int, ...]:
        """The bodies whose current pose a "body"-relative mocap action reads."""
        return tuple(m.welded for m in self.mocaps if m.relative_to == "body")

    def apply(
        self,
        outputs: np.ndarray,
        qpos: np.ndarray,
        targets: np.ndarray,
        welded: np.ndarray | None = None,
    ) -> tuple[np.ndarray, np.ndarray]:
        """The ctrl and mocap targets of a batch at a control instant.

        Args:
          outputs: (n, n_outputs) the policy's answer.
          qpos: (n, nq) the current joint positions.
          targets: (n, nmocap, 7) the mocap targets (pos, quat w-x-y-z) in force until now.
          welded: (n, len(welded_bodies), 7) those bodies' current poses (xpos, xquat).

        Returns:
          ctrl (n, nu) and the new targets (n, nmocap, 7).
        """
        n = len(outputs)
        if self.passthrough:
            return outputs, targets
        ctrl = np.zeros((n, self.nu))
        for c in self.controls:
            value = c.scale * outputs[:, c.column]
            for j, actuator in enumerate(c.actuators):
                signed = value if c.sign(j) == 1 else -value  # a negation is exact
                ctrl[:, actuator] = signed if c.qpos is None else qpos[:, c.qpos[j]] + signed
        if not self.mocaps:  # actuators alone (a column driving several): no target moves
            return ctrl, targets
        new = targets.copy()
        w = 0
        for m in self.mocaps:
            step = m.scale * outputs[:, m.column : m.column + 3]
            if m.relative_to == "absolute":
                pos, quat = step, targets[:, m.mocap, 3:]
            else:
                if m.max_step is not None:
                    step = np.clip(step, -m.max_step, m.max_step)
                if m.relative_to == "target":
                    reference = targets[:, m.mocap]
                else:
                    reference = welded[:, w]
                    w += 1
                pos, quat = reference[:, :3] + step, reference[:, 3:]
            if m.low is not None:
                pos = np.clip(pos, m.low, m.high)
            if m.orientation is not None:
                quat = np.broadcast_to(m.orientation, quat.shape)
            elif m.orientation_offset is not None:
                quat = quat + m.orientation_offset
            new[:, m.mocap, :3] = pos
            new[:, m.mocap, 3:] = quat
        return ctrl, new


def initial_targets(models: list[mujoco.MjModel]) -> np.ndarray:
    """(n, nmocap, 7) each episode's mocap poses at its start: its model's (`body_pos`,
    `body_quat`), from which every reset, `mujoco.rollout`'s included, takes them."""
    out = np.empty((len(models), models[0].nmocap, 7))
    bodies = np.flatnonzero(models[0].body_mocapid >= 0)
    order = models[0].body_mocapid[bodies]
    for i, m in enumerate(models):
        out[i, order, :3] = m.body_pos[bodies]
        out[i, order, 3:] = m.body_quat[bodies]
    return out


def body_poses(
    models: list[mujoco.MjModel], states: np.ndarray, bodies: tuple[int, ...], data: mujoco.MjData
) -> np.ndarray:
    """(n, len(bodies), 7) the bodies' world poses (xpos, xquat) at each mjSTATE_FULLPHYSICS
    state (n, nstate): `mj_setState` then `mj_kinematics` on `data`, episode i on models[i]."""
    out = np.empty((len(states), len(bodies), 7))
    for i, (m, state) in enumerate(zip(models, states, strict=True)):
        mujoco.mj_setState(m, data, state, FULLPHYSICS)
        mujoco.mj_kinematics(m, data)
        out[i, :, :3] = data.xpos[list(bodies)]
        out[i, :, 3:] = data.xquat[list(bodies)]
    return out


def qpos_of(states: np.ndarray, nq: int) -> np.ndarray:
    """(n, nq) the joint positions of mjSTATE_FULLPHYSICS rows (n, nstate)."""
    return states[:, STATE_QPOS : STATE_QPOS + nq]
