"""What a closed-loop policy's output columns drive (`ClosedLoop(actions=...)`): actuators'
ctrl (`Control`) and mocap bodies' targets (`MocapAction`), in the policy's output order.

With no actions declared the policy's output is every actuator's ctrl, in order. The engine's
side (the rule applied at each control instant) is `mjtrial.sim.actuation`.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import KW_ONLY, dataclass

import mujoco
import numpy as np

from mjtrial.sim.actuation import RELATIVE_TO, Actuation, ControlColumn, MocapColumns
from mjtrial.task.declare import TaskError, _element


@dataclass(frozen=True)
class Control:
    """One output column driving one or more actuators: ctrl = scale * value, or, `relative`,
    the position of each actuator's joint at the control instant plus scale * value
    (gymnasium-robotics' Fetch drives two position servos of a hand so from one column).

    `signs`: +1 or -1 per actuator, multiplying the value for that actuator: robosuite's and
    Metaworld's hands drive their two jaws with [a, -a] from one column, `signs=(1, -1)`.
    """

    actuators: str | tuple[str, ...]
    _: KW_ONLY
    relative: bool = False
    scale: float = 1.0
    signs: tuple[int, ...] | None = None
    size = 1

    def __post_init__(self) -> None:
        if isinstance(self.actuators, str):
            object.__setattr__(self, "actuators", (self.actuators,))
        else:
            object.__setattr__(self, "actuators", tuple(self.actuators))
        if self.signs is not None:
            object.__setattr__(self, "signs", tuple(self.signs))

    def bind(self, model: mujoco.MjModel, column: int) -> ControlColumn:
        if not self.actuators:
            raise TaskError("expected at least one actuator")
        if not np.isfinite(self.scale):
            raise TaskError(f"scale: expected a finite number, got {self.scale!r}")
        signs = ()
        if self.signs is not None:
            if len(self.signs) != len(self.actuators) or any(s not in (1, -1) for s in self.signs):
                raise TaskError(
                    f"signs: expected +1 or -1 for each of the {len(self.actuators)} actuators, "
                    f"got {list(self.signs)}"
                )
            signs = tuple(int(s) for s in self.signs)
        index = [_element(model, mujoco.mjtObj.mjOBJ_ACTUATOR, a) for a in self.actuators]
        qpos = None
        if self.relative:
            qpos = []
            for a, i in zip(self.actuators, index, strict=True):
                if model.actuator_trntype[i] != mujoco.mjtTrn.mjTRN_JOINT:
                    raise TaskError(f"relative: expected actuator {a!r} to drive a joint")
                qpos.append(int(model.jnt_qposadr[model.actuator_trnid[i, 0]]))
            qpos = np.array(qpos)
        return ControlColumn(column, np.array(index), qpos, self.scale, signs)


def _quat(name: str, value: Sequence[float] | None) -> np.ndarray | None:
    if value is None:
        return None
    out = np.asarray(value, dtype=np.float64)
    if out.shape != (4,) or not np.isfinite(out).all():
        raise TaskError(f"{name}: expected 4 finite numbers (w, x, y, z), got {value!r}")
    return out


@dataclass(frozen=True)
class MocapAction:
    """Three output columns (x, y, z) moving a mocap body's target position, set at each
    control instant and held until the next.

    Attributes:
      body: the mocap body.
      relative_to: "absolute" (target = scale * value), "target" (the previous target plus
        scale * value, Metaworld's rule; the first is the body's pose at the episode's start)
        or "body" (the pose of the body welded to it plus scale * value, gymnasium-robotics'
        Fetch: as there, the pose `data.xpos` holds after the last `mj_step`, which is the
        state's one physics step before the control instant; the initial state's at the
        first instant).
      scale: multiplies the values.
      max_step: the scaled step clipped to [-max_step, max_step] per axis (relative only).
      low, high: the box the target position is clipped to (both or neither).
      orientation: a fixed target quaternion (w, x, y, z); by default the reference's
        (the previous target's, or the welded body's for "body").
      orientation_offset: added to the welded body's quaternion ("body" only): Fetch sets
        xquat + (1, 0, 1, 0); MuJoCo normalizes a mocap quaternion.
    """

    body: str
    _: KW_ONLY
    relative_to: str = "absolute"
    scale: float = 1.0
    max_step: float | None = None
    low: tuple[float, float, float] | None = None
    high: tuple[float, float, float] | None = None
    orientation: tuple[float, float, float, float] | None = None
    orientation_offset: tuple[float, float, float, float] | None = None
    size = 3

    def bind(self, model: mujoco.MjModel, column: int) -> MocapColumns:
        body = _element(model, mujoco.mjtObj.mjOBJ_BODY, self.body)
        mocap = int(model.body_mocapid[body])
        if mocap < 0:
            raise TaskError(f"expected body {self.body!r} to be a mocap body")
        numbers = {"scale": self.scale, "max_step": self.max_step, "low": self.low}
        for name, value in (*numbers.items(), ("high", self.high)):
            if value is not None and not np.isfinite(np.asarray(value, dtype=float)).all():
                raise TaskError(f"{name}: expected finite numbers, got {value!r}")
        if self.relative_to not in RELATIVE_TO:
            raise TaskError(
                f"relative_to: expected one of {list(RELATIVE_TO)}, got {self.relative_to!r}"
            )
        if self.max_step is not None and (self.relative_to == "absolute" or self.max_step <= 0):
            raise TaskError("max_step: expected a number > 0 with a relative action")
        if (self.low is None) != (self.high is None):
            raise TaskError("low, high: expected both or neither")
        low = high = None
        if self.low is not None:
            low, high = np.asarray(self.low, float), np.asarray(self.high, float)
            if low.shape != (3,) or high.shape != (3,) or not (low <= high).all():
                raise TaskError("low, high: expected 3 numbers each, low <= high")
        if self.orientation is not None and self.orientation_offset is not None:
            raise TaskError("orientation, orientation_offset: expected at most one")
        if self.orientation_offset is not None and self.relative_to != "body":
            raise TaskError('orientation_offset: expected relative_to="body"')
        welded = _welded_body(model, body) if self.relative_to == "body" else -1
        return MocapColumns(
            column,
            mocap,
            self.relative_to,
            welded,
            float(self.scale),
            None if self.max_step is None else float(self.max_step),
            low,
            high,
            _quat("orientation", self.orientation),
            _quat("orientation_offset", self.orientation_offset),
        )


def _welded_body(model: mujoco.MjModel, mocap_body: int) -> int:
    """The body a weld equality holds to the mocap body (the only one)."""
    found = []
    for e in range(model.neq):
        weld = model.eq_type[e] == mujoco.mjtEq.mjEQ_WELD
        if not weld or model.eq_objtype[e] != mujoco.mjtObj.mjOBJ_BODY:
            continue
        pair = (int(model.eq_obj1id[e]), int(model.eq_obj2id[e]))
        if mocap_body in pair:
            found.append(pair[1] if pair[0] == mocap_body else pair[0])
    if len(found) != 1:
        name = model.body(mocap_body).name
        raise TaskError(
            f'relative_to="body": expected one body weld to mocap body {name!r}, found {len(found)}'
        )
    return found[0]


def bind_actions(model: mujoco.MjModel, actions: Sequence[Control | MocapAction]) -> Actuation:
    """The declared actions bound to the model, columns in declaration order; `TaskError`
    naming the action otherwise (no actions: every actuator's ctrl)."""
    if not actions:
        return Actuation.every_actuator(model)
    controls, mocaps, column = [], [], 0
    driven: dict[int, int] = {}
    for k, action in enumerate(actions):
        try:
            if isinstance(action, Control):
                bound = action.bind(model, column)
                for a in bound.actuators.tolist():
                    if a in driven:
                        name = model.actuator(a).name
                        raise TaskError(f"actuator {name!r} is driven by actions[{driven[a]}] too")
                    driven[a] = k
                controls.append(bound)
            elif isinstance(action, MocapAction):
                bound = action.bind(model, column)
                if any(m.mocap == bound.mocap for m in mocaps):
                    raise TaskError(f"mocap body {action.body!r} is moved by another action too")
                mocaps.append(bound)
            else:
                kind = type(action).__name__
                raise TaskError(f"expected a Control or a MocapAction, got {kind}")
        except TaskError as err:
            raise TaskError(f"actions[{k}]: {err}") from None
        column += action.size
    return Actuation(model.nu, model.nmocap, column, tuple(controls), tuple(mocaps))
