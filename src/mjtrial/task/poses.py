"""Poses of bodies and sites as observations (`Observation.body_position` and its siblings).

A pose depends on the kinematics, and so on each episode's own model (a model parameter may
move a body's offset): it is computed on that model at the measured state, `mj_setState` then
`mj_kinematics` (what `mj_forward` starts with; positions and orientations need no more), in the
engine and in `closed_loop.reference_episode` alike, since both read observations through
`BoundTask.observer`.

A mocap body's pose is not in the mjSTATE_FULLPHYSICS state, so neither it nor the pose of
anything that moves with one (a body under it, a site on it, a frame there) can be computed
from the measured state alone: such an observation is refused for now (mocap actions, which
move a mocap body during an episode, are planned; a task may meanwhile read the target it sets).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass

import mujoco
import numpy as np

from mjtrial.sim.physics import FULLPHYSICS
from mjtrial.task import address

# quantity -> (element kind, columns)
QUANTITIES = {
    "body_position": ("body", 3),
    "site_position": ("site", 3),
    "body_orientation": ("body", 4),
    "site_orientation": ("site", 4),
}


class PoseError(ValueError):
    """A pose observation's element that does not resolve or cannot be read (one line)."""


def _element(model: mujoco.MjModel, kind: str, ref: str) -> int:
    try:
        return address.resolve(model, kind, ref)
    except address.AddressError as err:
        raise PoseError(str(err)) from None


PoseRead = Callable[[mujoco.MjData], np.ndarray]
"""(data after `mj_kinematics`) -> (size,) the pose observation's value."""


def _moves_with_mocap(model: mujoco.MjModel, body: int) -> bool:
    while body > 0:
        if model.body_mocapid[body] >= 0:
            return True
        body = int(model.body_parentid[body])
    return False


def _frame_of(model: mujoco.MjModel, kind: str, ref: str) -> tuple[int, int]:
    """(element index, its body) of a body or a site; refuses a mocap-driven one."""
    index = _element(model, kind, ref)
    body = index if kind == "body" else int(model.site_bodyid[index])
    if _moves_with_mocap(model, body):
        raise PoseError(
            f"{kind} {ref!r} is or moves with a mocap body, whose pose an mjSTATE_FULLPHYSICS "
            "state does not hold; expected a body or site driven by the physics"
        )
    return index, body


@dataclass(frozen=True)
class Pose:
    """What a pose observation reads: `quantity` (a key of `QUANTITIES`) of the body or site
    `element`, in the world frame or in the frame of `frame`: a body's (by name or address,
    `mjtrial.task.address`), else the site of that name."""

    quantity: str
    element: str
    frame: str | None = None

    @property
    def size(self) -> int:
        return QUANTITIES[self.quantity][1]

    def bind(self, model: mujoco.MjModel) -> PoseRead:
        """The read of the value from data after `mj_kinematics`; a `PoseError` (one line) if an
        element does not resolve or moves with a mocap body."""
        kind, _ = QUANTITIES[self.quantity]
        index, _ = _frame_of(model, kind, self.element)
        position = self.quantity.endswith("position")
        if kind == "body":
            get = (lambda d: d.xpos[index]) if position else (lambda d: d.xquat[index])
        else:
            get = (
                (lambda d: d.site_xpos[index])
                if position
                else (lambda d: _quat(d.site_xmat[index]))
            )
        if self.frame is None:
            return lambda d: np.array(get(d))
        # a body's frame, else a site's (Fetch names a body and a site `object0`: the body)
        is_site = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_BODY, self.frame) < 0 and (
            mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_SITE, self.frame) >= 0
        )
        frame_kind = "site" if is_site else "body"
        f, _ = _frame_of(model, frame_kind, self.frame)
        if frame_kind == "body":
            f_pos, f_mat = (lambda d: d.xpos[f]), (lambda d: d.xmat[f])
        else:
            f_pos, f_mat = (lambda d: d.site_xpos[f]), (lambda d: d.site_xmat[f])
        if position:
            # R_f^T (p - p_f): the point in the frame's coordinates
            return lambda d: f_mat(d).reshape(3, 3).T @ (get(d) - f_pos(d))

        def relative(d: mujoco.MjData) -> np.ndarray:
            conj, out = np.empty(4), np.empty(4)
            mujoco.mju_negQuat(conj, _quat(f_mat(d)))
            mujoco.mju_mulQuat(out, conj, get(d))
            return out

        return relative


def _quat(mat: np.ndarray) -> np.ndarray:
    out = np.empty(4)
    mujoco.mju_mat2Quat(out, mat)
    return out


class PoseProbe:
    """The pose observations of a batch at a control instant: each row's state set on its own
    model, `mj_kinematics`, every pose read. Computed once per instant for all the pose
    observations an observer reads (`values`, cached on the instant)."""

    def __init__(self, models: Sequence[mujoco.MjModel], reads: Sequence[PoseRead]) -> None:
        self.models, self.reads = list(models), list(reads)
        self.data = mujoco.MjData(self.models[0])
        self.instant: tuple[int, int] | None = None
        self.cached: list[np.ndarray] = []

    def values(self, k: int, states: np.ndarray) -> list[np.ndarray]:
        """Per read, its (n, size) values at the measured states (n, nstate)."""
        if self.instant != (k, id(states)):
            if len(states) != len(self.models):
                raise ValueError(
                    f"expected {len(self.models)} states (one per model), got {len(states)}"
                )
            rows = []
            for m, state in zip(self.models, states, strict=True):
                mujoco.mj_setState(m, self.data, state, FULLPHYSICS)
                mujoco.mj_kinematics(m, self.data)
                rows.append([read(self.data) for read in self.reads])
            self.cached = [np.stack([r[j] for r in rows]) for j in range(len(self.reads))]
            self.instant = (k, id(states))
        return self.cached
