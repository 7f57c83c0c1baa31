"""How a state parameter is applied to an episode: to its model (`BodyMass`, `ModelValue`,
`MocapPosition`, `Rotation`), to its reset data (`JointPosition`, `JointVelocity`), by the
task's own function (`Custom`), by the controller's pushes (`DISTURBANCE`) or by the task's
`episode_setup` (`EPISODE_SETUP`). Each `bind(model)` resolves the names once and returns
`apply(model, data, value)`; a name the model lacks, or a field MuJoCo would ignore, is a
`TaskError` (one line).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import mujoco
import numpy as np

from mjtrial.task import address
from mjtrial.task.declare import TaskError, _element


def _free_joint(model: mujoco.MjModel, body: int) -> int | None:
    """The free joint of a body placed by one (MuJoCo then ignores its `pos` and `quat`: its
    pose is the joint's qpos), else None."""
    joint = model.body_jntadr[body]
    free = model.body_jntnum[body] and model.jnt_type[joint] == mujoco.mjtJoint.mjJNT_FREE
    return int(joint) if free else None


def _refuse_free_body(model: mujoco.MjModel, body: int, name: str, what: str) -> None:
    """Refuse to set a free body's `body_pos` or `body_quat`: no episode would see it."""
    joint = _free_joint(model, body)
    if joint is None:
        return
    free = mujoco.mj_id2name(model, mujoco.mjtObj.mjOBJ_JOINT, joint)
    free = repr(free) if free else f"#{joint}"
    instead = (
        f"a JointPosition on joint {free} (index 0, 1, 2: x, y, z)"
        if what == "pos"
        else f"a Custom applier (stage 'initial') that turns joint {free}'s quaternion "
        "(qpos[3:7], w-x-y-z) in the initial state"
    )
    raise TaskError(
        f"body {name!r} is placed by its free joint {free}, so MuJoCo ignores its body {what} "
        f"(no episode would differ); expected {instead}"
    )


def _own_frame(model: mujoco.MjModel, kind: str, index: int) -> None:
    """Make the compiler's shortcut forget a geom's or site's frame: one compiled at its body's
    frame (`geom_sameframe`, `site_sameframe`) has its `pos` and `quat` ignored by
    `mj_kinematics`, so a position or orientation set per episode would not move it."""
    if kind in ("geom", "site"):
        getattr(model, f"{kind}_sameframe")[index] = 0


@dataclass(frozen=True)
class BodyMass:
    """Sets a body's mass (inertia as compiled); constants are recomputed (`mj_setConst`)."""

    body: str
    stage = "model"
    sets = True  # writes its value whatever was there: a model copy can be reused

    def bind(self, model: mujoco.MjModel) -> Callable[[mujoco.MjModel, mujoco.MjData, float], None]:
        index = _element(model, mujoco.mjtObj.mjOBJ_BODY, self.body)

        def apply(m: mujoco.MjModel, d: mujoco.MjData, value: float) -> None:
            m.body_mass[index] = value

        return apply


@dataclass(frozen=True)
class JointPosition:
    """Adds the value to a joint's position in the reset pose (a hinge's angle, a slide's
    offset; `index` picks a component of a free or ball joint's qpos)."""

    joint: str
    index: int = 0
    stage = "initial"

    def bind(self, model: mujoco.MjModel) -> Callable[[mujoco.MjModel, mujoco.MjData, float], None]:
        adr = model.jnt_qposadr[_element(model, mujoco.mjtObj.mjOBJ_JOINT, self.joint)] + self.index

        def apply(m: mujoco.MjModel, d: mujoco.MjData, value: float) -> None:
            d.qpos[adr] = d.qpos[adr] + value

        return apply


@dataclass(frozen=True)
class JointVelocity:
    """Sets a joint's velocity (`index`: a component of a multi-dof joint's qvel)."""

    joint: str
    index: int = 0
    stage = "initial"

    def bind(self, model: mujoco.MjModel) -> Callable[[mujoco.MjModel, mujoco.MjData, float], None]:
        adr = model.jnt_dofadr[_element(model, mujoco.mjtObj.mjOBJ_JOINT, self.joint)] + self.index

        def apply(m: mujoco.MjModel, d: mujoco.MjData, value: float) -> None:
            d.qvel[adr] = value

        return apply


@dataclass(frozen=True)
class ModelValue:
    """Sets one number of an element of the episode's model, by MuJoCo's named accessor:
    `ModelValue("geom", "target", "pos", 0)` sets `model.geom("target").pos[0]` (a goal's x).
    `kind` is an `MjModel` accessor (`body`, `geom`, `site`, `joint`, `actuator`, `tendon`,
    `eq`, `sensor`, ...), `attribute` that element's field without its prefix (`pos`, `size`,
    `friction`, `damping`, `gear`), `index` the number within it. Applied before constants
    are recomputed, like every model parameter."""

    kind: str
    name: str
    attribute: str
    index: int = 0
    stage = "model"
    sets = True  # writes its value whatever was there: a model copy can be reused

    def bind(self, model: mujoco.MjModel) -> Callable[[mujoco.MjModel, mujoco.MjData, float], None]:
        what = f"{self.kind} {self.name!r}"
        try:
            accessor = getattr(model, self.kind)
            # an address (`#0`, `on:<name>`) for the kinds it covers, else MuJoCo's lookup
            ref = _element(model, self.kind, self.name) if self.kind in address.KINDS else self.name
            element = accessor(ref)
        except (AttributeError, TypeError):
            raise TaskError(f"expected an MjModel element kind, got {self.kind!r}") from None
        except KeyError:
            raise TaskError(f"expected a {self.kind} named {self.name!r} in the model") from None
        field_ = np.atleast_1d(getattr(element, self.attribute, None))
        if field_.dtype.kind != "f" or not 0 <= self.index < field_.size:
            raise TaskError(
                f"{what}: expected a numeric field {self.attribute!r} with an "
                f"index {self.index} (it has {field_.size} numbers)"
            )
        if self.kind == "body" and self.attribute in ("pos", "quat"):
            _refuse_free_body(model, element.id, self.name, self.attribute)
        kind, attribute, index = self.kind, self.attribute, self.index
        name = element.id  # an index: the element may be unnamed (`#0`, `on:<name>`)
        moves = attribute in ("pos", "quat")

        def apply(m: mujoco.MjModel, d: mujoco.MjData, value: float) -> None:
            target = getattr(m, kind)(name)
            getattr(target, attribute)[index] = value
            if moves:
                _own_frame(m, kind, target.id)

        return apply


@dataclass(frozen=True)
class MocapPosition:
    """Sets a mocap body's position along one axis (0, 1, 2: x, y, z): in the episode's model
    (`body_pos`), from which every reset, `mujoco.rollout`'s included, takes the mocap pose (an
    mjSTATE_FULLPHYSICS state does not hold it, so a value set in the reset data alone would be
    lost), and in the reset data."""

    body: str
    axis: int
    stage = "model"
    sets = True  # writes its value whatever was there: a model copy can be reused

    def bind(self, model: mujoco.MjModel) -> Callable[[mujoco.MjModel, mujoco.MjData, float], None]:
        mocap = model.body_mocapid[_element(model, mujoco.mjtObj.mjOBJ_BODY, self.body)]
        if mocap < 0:
            raise TaskError(f"expected body {self.body!r} to be a mocap body")
        if self.axis not in (0, 1, 2):
            raise TaskError(f"axis: expected 0, 1 or 2, got {self.axis!r}")
        axis, body = self.axis, model.body_mocapid.tolist().index(mocap)

        def apply(m: mujoco.MjModel, d: mujoco.MjData, value: float) -> None:
            m.body_pos[body, axis] = value
            d.mocap_pos[mocap, axis] = value

        return apply


@dataclass(frozen=True)
class Rotation:
    """Turns a body, geom or site by `value` radians about one of its own axes (0, 1, 2: x, y,
    z) from its orientation in the model as loaded: `Rotation("geom", "target", 2)` yaws a goal
    marker. The quaternion is set from the nominal one each time (`q = q0 * (cos v/2, sin v/2
    along the axis)`), so a reused model copy gets the value a fresh one would; a mocap body's
    pose is set in the reset data too, as `MocapPosition` does.

    A body placed by a free joint is refused: MuJoCo ignores its `body_quat` (its pose is the
    joint's qpos). Turning that qpos instead would make this an edit of the initial state,
    applied after the reset and the task's `episode_setup`, from an orientation the keyframe or
    the setup gives rather than the model's: another parameter, which a `Custom` says plainly."""

    kind: str
    name: str
    axis: int
    stage = "model"
    sets = True  # from the nominal orientation, whatever was there: a model copy can be reused

    def bind(self, model: mujoco.MjModel) -> Callable[[mujoco.MjModel, mujoco.MjData, float], None]:
        kinds = {
            "body": (mujoco.mjtObj.mjOBJ_BODY, "body_quat"),
            "geom": (mujoco.mjtObj.mjOBJ_GEOM, "geom_quat"),
            "site": (mujoco.mjtObj.mjOBJ_SITE, "site_quat"),
        }
        if self.kind not in kinds:
            raise TaskError(f"kind: expected one of {list(kinds)}, got {self.kind!r}")
        if self.axis not in (0, 1, 2):
            raise TaskError(f"axis: expected 0, 1 or 2, got {self.axis!r}")
        obj, field_ = kinds[self.kind]
        index = _element(model, obj, self.name)
        if self.kind == "body":
            _refuse_free_body(model, index, self.name, "quat")
        nominal = getattr(model, field_)[index].copy()
        mocap = model.body_mocapid[index] if self.kind == "body" else -1
        kind, axis = self.kind, self.axis

        def apply(m: mujoco.MjModel, d: mujoco.MjData, value: float) -> None:
            turn = np.zeros(4)
            turn[0], turn[1 + axis] = np.cos(value / 2), np.sin(value / 2)
            quat = getattr(m, field_)[index]
            mujoco.mju_mulQuat(quat, nominal, turn)
            _own_frame(m, kind, index)
            if mocap >= 0:
                d.mocap_quat[mocap] = quat

        return apply


@dataclass(frozen=True)
class Custom:
    """A function of the task's own: `fn(model, data, value)`, applied to the episode's model
    (`stage="model"`, before constants are recomputed) or to its reset data (`"initial"`)."""

    fn: Callable[[mujoco.MjModel, mujoco.MjData, float], None]
    stage: str = "initial"

    def bind(self, model: mujoco.MjModel) -> Callable[[mujoco.MjModel, mujoco.MjData, float], None]:
        return self.fn


@dataclass(frozen=True)
class Disturbance:
    """Read by the closed-loop controller's `pushes`, not applied to the initial state."""

    stage = "disturbance"

    def bind(self, model: mujoco.MjModel) -> None:
        return None


DISTURBANCE = Disturbance()
"""A state parameter's `apply` when the closed-loop controller's `pushes` read it (a
disturbance during the episode, not an initial condition)."""


@dataclass(frozen=True)
class ReadBySetup:
    """Applied by the task's `episode_setup`, which is given every state value: a suite's reset
    places objects and goals relative to where its own settling left the robot, which no
    declared applier can express."""

    stage = "setup"

    def bind(self, model: mujoco.MjModel) -> None:
        return None


EPISODE_SETUP = ReadBySetup()
"""A state parameter's `apply` when the task's `episode_setup` reads it (an object placed relative
to where the suite's own reset left the robot)."""


@dataclass(frozen=True)
class Goal:
    """A goal that lives in no model element (a target angle, a commanded velocity): applied
    to nothing, read by an observation (`Observation.episode_value`) the policy reads, or by
    `success` or `measure` (`Episodes.values`). The config check refuses one that nothing
    reads."""

    stage = "goal"

    def bind(self, model: mujoco.MjModel) -> None:
        return None


GOAL = Goal()
"""A state parameter's `apply` when it is a goal no model element holds: the policy's
observations or the success test read it (`Goal`)."""
