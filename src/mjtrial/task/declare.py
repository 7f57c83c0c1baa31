"""What a task declares: its state parameters (how each is applied: `mjtrial.task.appliers`),
its protocol parameters, observations, controllers, measures, outcomes and failure categories,
and the errors a task raises.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Protocol

import mujoco
import numpy as np

from mjtrial.sim.closed_loop import BatchPolicy, Pushes, Timing
from mjtrial.sim.physics import STATE_QPOS
from mjtrial.task import address
from mjtrial.task.observation_model import ObservationModel
from mjtrial.task.poses import Pose

UNHEALTHY = "simulation unhealthy"  # the first failure category of every task
# A policy file's action went NaN or infinite (`mjtrial.policy_files.file`): control stopped.
NONFINITE_ACTION = "non-finite action"


class TaskError(ValueError):
    """A task file that cannot be loaded, or whose declarations or functions are wrong."""


class NotAFunctionError(TaskError):
    """A task function (`episode_setup`, `valid_state`) whose result depends on more than its
    arguments: no run of the task can be reproduced."""


class ModelCheckError(TaskError):
    """The task's `check_model` refused the model; `problem` says why, without the file."""

    def __init__(self, model: Path, problem: str) -> None:
        super().__init__(f"{model}: {problem}")
        self.problem = problem


def _element(model: mujoco.MjModel, kind: mujoco.mjtObj | str, name: str) -> int:
    """The index of the element `name` gives: a name, `#<index>` or `on:<name>`
    (`mjtrial.task.address`); a `TaskError` (one line) when it does not resolve."""
    try:
        return address.resolve(model, kind, name)
    except address.AddressError as err:
        raise TaskError(str(err)) from None


class Applier(Protocol):
    """How a state parameter is applied (`mjtrial.task.appliers`: `BodyMass`, `JointPosition`,
    `JointVelocity`, `ModelValue`, `MocapPosition`, `Rotation`, `Custom`, `DISTURBANCE`,
    `EPISODE_SETUP`, `GOAL`): its `stage` ("model", "initial", "disturbance", "setup" or
    "goal") and
    `bind(model)`, which resolves its names and returns `apply(model, data, value)` (None for
    a value the controller or the setup reads)."""

    stage: str

    def bind(
        self, model: mujoco.MjModel
    ) -> Callable[[mujoco.MjModel, mujoco.MjData, float], None] | None: ...


@dataclass(frozen=True)
class StateParameter:
    """One column of the states table: drawn uniformly in [low, high] (config `states.ranges`
    may change the range, `states.distributions` draw it from a normal or a truncated normal
    instead: `mjtrial.design.states`), then applied to each episode."""

    name: str
    unit: str
    low: float
    high: float
    apply: Applier
    description: str = ""
    nominal: float | None = None  # the careless evaluation's single state (default: mid-range)

    @property
    def nominal_value(self) -> float:
        return (self.low + self.high) / 2 if self.nominal is None else self.nominal


@dataclass(frozen=True)
class ProtocolParameter:
    """A value conditions, sweeps and variants may set; the config schema is built from it."""

    name: str
    unit: str
    default: float
    minimum: float | None = None
    maximum: float | None = None
    exclusive_minimum: bool = False  # minimum < value rather than minimum <= value
    integer: bool = False
    description: str = ""
    required: bool = False  # every condition must set it (else the default applies)

    def schema(self) -> dict[str, Any]:
        """The JSON schema of the parameter's value."""
        return _number_schema(self)


def _number_schema(p: ProtocolParameter | Threshold) -> dict[str, Any]:
    out: dict[str, Any] = {
        "type": "integer" if getattr(p, "integer", False) else "number",
        "description": f"{p.description} ({p.unit})".strip() if p.unit else p.description,
    }
    # a whole bound as an integer: the config's messages say "expected > 0", not "> 0.0"
    if p.minimum is not None:
        out["exclusiveMinimum" if p.exclusive_minimum else "minimum"] = _plain(p.minimum)
    if p.maximum is not None:
        out["maximum"] = _plain(p.maximum)
    return out


def _plain(value: float) -> float | int:
    return int(value) if float(value).is_integer() else value


# --------------------------------------------------------------------------------------------
# Observations, controllers, outcomes
# --------------------------------------------------------------------------------------------


def _errors(**parameters: str | None) -> ObservationModel | None:
    return ObservationModel(**parameters) if any(parameters.values()) else None


@dataclass(frozen=True)
class Observation:
    """A quantity the controller may read: `read(model)` gives a function from a batch of
    mjSTATE_FULLPHYSICS rows (n, nstate) to (n, size) values, or `parameter` names a state
    parameter whose per-episode value it is (`Observation.episode_value`), or `sensor_name`
    a sensor of the model (`Observation.sensor`), or `pose` a body's or site's pose
    (`Observation.body_position` and its siblings); `columns(model)` is its width. `source`
    names the real sensor it stands for (encoder, IMU, camera pose estimate); None marks it
    privileged: the simulator knows it, a robot would not. `errors`: its noise, bias,
    quantization and dropped readings, as protocol parameters (`ObservationModel`; the
    constructors' `noise`, `bias`, `quantum` and `dropout` arguments build it)."""

    name: str
    source: str | None
    read: Callable[[mujoco.MjModel], Callable[[np.ndarray], np.ndarray]] | None
    size: int = 1
    parameter: str | None = None  # a state parameter's per-episode value (`episode_value`)
    sensor_name: str | None = None  # a sensor of the model (`sensor`)
    errors: ObservationModel | None = None
    pose: Pose | None = None  # a body's or site's pose (`body_position`, ...: `task.poses`)

    def columns(self, model: mujoco.MjModel) -> int:
        """Its number of columns in the policy's input: a sensor's dimension in `model` (a
        `framepos` has 3), else `size`."""
        if self.sensor_name is None:
            return self.size
        return int(model.sensor_dim[_element(model, mujoco.mjtObj.mjOBJ_SENSOR, self.sensor_name)])

    @classmethod
    def _pose(
        cls,
        quantity: str,
        name: str,
        element: str,
        frame: str | None,
        source: str | None,
        errors: dict[str, str | None],
    ) -> Observation:
        pose = Pose(quantity, element, frame)
        return cls(name, source, None, pose.size, errors=_errors(**errors), pose=pose)

    @classmethod
    def body_position(
        cls,
        name: str,
        body: str,
        *,
        source: str | None,
        frame: str | None = None,
        **errors: str | None,
    ) -> Observation:
        """A body's position (`xpos`, 3 columns), in the world frame or in `frame`'s (a body's,
        else a site's): computed on each episode's own model at the measured state
        (`mjtrial.task.poses`; a mocap body, or one that moves with one, is refused for now).
        `errors`: as for `Observation.sensor`."""
        return cls._pose("body_position", name, body, frame, source, errors)

    @classmethod
    def site_position(
        cls,
        name: str,
        site: str,
        *,
        source: str | None,
        frame: str | None = None,
        **errors: str | None,
    ) -> Observation:
        """A site's position (`site_xpos`, 3 columns); as `Observation.body_position`."""
        return cls._pose("site_position", name, site, frame, source, errors)

    @classmethod
    def body_orientation(
        cls,
        name: str,
        body: str,
        *,
        source: str | None,
        frame: str | None = None,
        **errors: str | None,
    ) -> Observation:
        """A body's orientation, a unit quaternion w-x-y-z (`xquat`, 4 columns); in `frame`'s:
        conj(q_frame) * q. As `Observation.body_position`."""
        return cls._pose("body_orientation", name, body, frame, source, errors)

    @classmethod
    def site_orientation(
        cls,
        name: str,
        site: str,
        *,
        source: str | None,
        frame: str | None = None,
        **errors: str | None,
    ) -> Observation:
        """A site's orientation, w-x-y-z (from `site_xmat`, 4 columns); as
        `Observation.body_orientation`."""
        return cls._pose("site_orientation", name, site, frame, source, errors)

    @classmethod
    def free_joint(
        cls, name: str, joint: str, *, source: str | None, **errors: str | None
    ) -> Observation:
        """A free joint's position and orientation, 7 columns straight from `qpos` (x, y, z,
        then the quaternion w-x-y-z): an object's pose in the world. `errors`: as for
        `Observation.sensor`."""

        def read(model: mujoco.MjModel) -> Callable[[np.ndarray], np.ndarray]:
            index = _element(model, mujoco.mjtObj.mjOBJ_JOINT, joint)
            if model.jnt_type[index] != mujoco.mjtJoint.mjJNT_FREE:
                kind = mujoco.mjtJoint(model.jnt_type[index]).name.removeprefix("mjJNT_").lower()
                raise TaskError(f"joint {joint!r} is a {kind} joint; expected a free joint")
            column = STATE_QPOS + model.jnt_qposadr[index]
            return lambda states: states[:, column : column + 7]

        return cls(name, source, read, 7, errors=_errors(**errors))

    @classmethod
    def sensor(
        cls,
        name: str,
        sensor: str,
        *,
        source: str | None,
        noise: str | None = None,
        bias: str | None = None,
        quantum: str | None = None,
        dropout: str | None = None,
    ) -> Observation:
        """A `<sensor>` of the model, by name: its value is what `data.sensordata` holds after
        `mj_forward` at the measured state (the state `Timing.latency_steps` before the control
        instant), all its components (a `framepos` gives 3 columns). A position or velocity
        sensor (`jointpos`, `framepos`, `gyro`, `velocimeter`, ...): an acceleration or force
        sensor's value would depend on the control and solver at that instant, and is refused.

        `noise`, `bias`, `quantum` and `dropout` name protocol parameters: the Gaussian noise's
        standard deviation, a constant offset, the resolution readings are rounded to, and the
        probability a reading is lost and the last one held (`ObservationModel`; the draws are
        each episode's own, the same under every condition)."""
        errors = _errors(noise=noise, bias=bias, quantum=quantum, dropout=dropout)
        return cls(name, source, None, sensor_name=sensor, errors=errors)

    @classmethod
    def episode_value(
        cls,
        name: str,
        parameter: str,
        *,
        source: str | None,
        noise: str | None = None,
        bias: str | None = None,
        quantum: str | None = None,
        dropout: str | None = None,
    ) -> Observation:
        """A state parameter's value in each episode, as the robot is given it: a goal drawn
        per episode and applied to the model (a target's position) is invisible in the physics
        state, so a goal-conditioned policy reads it here. `source` says how a real robot
        would know it ("the goal it is commanded", "motion capture"); None: privileged.
        `noise`, `bias`, `quantum`, `dropout`: as for `Observation.sensor` (a goal seen by a
        camera pose estimate, with its noise)."""
        errors = _errors(noise=noise, bias=bias, quantum=quantum, dropout=dropout)
        return cls(name, source, None, 1, parameter, errors=errors)

    @classmethod
    def joint_position(
        cls, name: str, joint: str, *, source: str | None, **errors: str | None
    ) -> Observation:
        """A joint's position (`qpos` at its address); `errors`: as for `Observation.sensor`."""

        def read(model: mujoco.MjModel) -> Callable[[np.ndarray], np.ndarray]:
            adr = model.jnt_qposadr[_element(model, mujoco.mjtObj.mjOBJ_JOINT, joint)]
            column = STATE_QPOS + adr
            return lambda states: states[:, column : column + 1]

        return cls(name, source, read, errors=_errors(**errors))

    @classmethod
    def joint_velocity(
        cls, name: str, joint: str, *, source: str | None, **errors: str | None
    ) -> Observation:
        """A joint's velocity (`qvel` at its address); `errors`: as for `Observation.sensor`."""

        def read(model: mujoco.MjModel) -> Callable[[np.ndarray], np.ndarray]:
            adr = model.jnt_dofadr[_element(model, mujoco.mjtObj.mjOBJ_JOINT, joint)]
            column = STATE_QPOS + model.nq + adr
            return lambda states: states[:, column : column + 1]

        return cls(name, source, read, errors=_errors(**errors))


@dataclass(frozen=True)
class OpenLoop:
    """A control sequence known before the episode: `controls(model, params)` gives the ctrl
    applied before each physics step, (n_steps, nu)."""

    controls: Callable[[mujoco.MjModel, Mapping[str, float]], np.ndarray]
    # its length without building it (the budget checks run before any large array is made)
    n_steps: Callable[[mujoco.MjModel, Mapping[str, float]], int] | None = None


@dataclass(frozen=True)
class ClosedLoop:
    """A policy on observations at the control rate.

    Attributes:
      policy: `policy(model, params)`, built once per condition on the nominal model.
      observations: the declared observations the policy reads, in the order it gets them.
      timing: `timing(model, params)`: control period, episode length, sensing latency.
      pushes: `pushes(model, values)`, the wrench pulse of each episode from the states'
        `DISTURBANCE` columns (`values[name]` is an array over the batch), or None.
      source: the file the policy and its observations come from when it is not the task file
        (a policy file's contract): errors about them name it.
      actions: what the policy's output columns drive, in order (`Control`, `MocapAction`);
        empty: every actuator's ctrl, in order.
      low_level: `low_level(model, params)` builds a controller run at every physics step
        between the policy and the actuators (`mjtrial.sim.low_level.LowLevelController`: an
        operational-space controller, joint impedance, ...), called once per slice of a batch;
        the policy's output columns are then its action. None: the columns drive the
        actuators (`actions`) and hold over each control period.
      carry_warmstart: carry the solver's warm start across control instants, as a suite's
        own `mj_step` loop does (Metaworld, gymnasium-robotics, robosuite); False: each control
        period starts from a zero warm start, as `mujoco.rollout` does by default. With a
        constraint active (a weld, a contact) the two differ in the last bits, and outcomes
        near a threshold can flip. A low-level controller always carries it.
    """

    policy: Callable[[mujoco.MjModel, Mapping[str, float]], BatchPolicy]
    observations: tuple[str, ...]
    timing: Callable[[mujoco.MjModel, Mapping[str, float]], Timing]
    pushes: Callable[[mujoco.MjModel, Mapping[str, np.ndarray]], Pushes] | None = None
    source: Path | None = None
    actions: tuple[Any, ...] = ()  # `Control`, `MocapAction` (mjtrial.task.actions)
    low_level: Callable[[mujoco.MjModel, Mapping[str, float]], Any] | None = None
    carry_warmstart: bool = False


SeriesRead = Callable[[np.ndarray, np.ndarray, np.ndarray], np.ndarray]
"""(rows (n, nstate) mjSTATE_FULLPHYSICS, sensors (n, nsensordata), ctrl (n, nu)) -> (n,)."""


@dataclass(frozen=True)
class Series:
    """A signal the recordings plot beside the 3D scene.

    Attributes:
      name: the series' name in the recording and the viewer.
      body: the body whose entity holds it (it shares that body's time-series chunk).
      plot: the title of the plot it is drawn in, with its unit ("joint angle (rad)"); series
        of one plot share it, in order of first appearance.
      read: `read(model)` gives a function from a batch of logged rows to the values.
    """

    name: str
    body: str
    plot: str
    read: Callable[[mujoco.MjModel], SeriesRead]

    @classmethod
    def joint_position(cls, name: str, joint: str, *, body: str, plot: str) -> Series:
        def read(model: mujoco.MjModel) -> SeriesRead:
            adr = model.jnt_qposadr[_element(model, mujoco.mjtObj.mjOBJ_JOINT, joint)]
            return lambda rows, sensors, ctrl: rows[:, STATE_QPOS + adr]

        return cls(name, body, plot, read)

    @classmethod
    def control(cls, name: str, actuator: str, *, body: str, plot: str) -> Series:
        def read(model: mujoco.MjModel) -> SeriesRead:
            index = _element(model, mujoco.mjtObj.mjOBJ_ACTUATOR, actuator)
            return lambda rows, sensors, ctrl: ctrl[:, index]

        return cls(name, body, plot, read)


@dataclass(frozen=True)
class Threshold:
    """A threshold of the failure categories (config `failure_taxonomy.<name>`)."""

    name: str
    unit: str
    default: float
    description: str = ""
    minimum: float | None = None
    maximum: float | None = None
    exclusive_minimum: bool = False

    def schema(self) -> dict[str, Any]:
        """The JSON schema of the threshold's value."""
        return _number_schema(self)


@dataclass(frozen=True)
class Measure:
    """A per-episode number the rollout table keeps (a column), with its unit. `recorded`: also
    a field of the episode's recording (shown when it is replayed)."""

    name: str
    unit: str
    description: str = ""
    recorded: bool = False


# Columns the engine gives every task's rollout table; a task may place them among its measures
# (by listing these), else they follow its measures in this order. Their values are the engine's.
STEPS_SIMULATED = Measure(
    "steps_simulated", "steps", "physics steps before a MuJoCo warning froze the episode"
)
"""Measure every episode gets from the engine: steps simulated before a warning froze it."""
NONFINITE = Measure("nonfinite", "", "the state went NaN or infinite")
"""Measure every episode gets from the engine: whether its state went NaN or infinite."""
WARNING = Measure("warning", "", "the MuJoCo warnings that stopped the episode, by name")
"""Measure every episode gets from the engine: the MuJoCo warnings that stopped it, by name."""
FAILURE_CATEGORY = Measure("failure_category", "", "the first failure category that applies")
"""Measure every episode gets from the engine: the first failure category that applies."""
ENGINE_MEASURES = (STEPS_SIMULATED, NONFINITE, WARNING, FAILURE_CATEGORY)


@dataclass(frozen=True)
class Episodes:
    """What a task's outcome functions read about a batch of finished episodes.

    Attributes:
      model: the nominal model of the condition.
      params: the condition's protocol parameters (defaults filled in).
      physics: (n, n_steps, nstate) mjSTATE_FULLPHYSICS after each step.
      sensordata: (n, n_steps, nsensordata) the sensors each step recorded: `mj_step` computes
        them before it integrates, so [:, j] are those of the state before step j + 1
        (`physics[:, j - 1]`, the initial state's for j = 0).
      healthy: (n,) False where a MuJoCo warning froze the episode or it went non-finite.
      ctrl: (n, n_steps, nu) the ctrl applied before each step (open loop: one sequence for
        every episode, broadcast).
      values: state parameter -> (n,) each episode's value (a goal drawn per episode, applied
        to the episode's own model, is read here: `model` is the condition's nominal one).
      mocap: (n, n_steps, nmocap, 7) the mocap targets (pos, quat w-x-y-z) during each step,
        or None when no action moves a mocap body (they stay at each episode's start pose).
    """

    model: mujoco.MjModel
    params: Mapping[str, float]
    physics: np.ndarray
    sensordata: np.ndarray
    healthy: np.ndarray
    ctrl: np.ndarray
    values: Mapping[str, np.ndarray] = field(default_factory=dict)
    mocap: np.ndarray | None = None


@dataclass(frozen=True)
class FailureCategory:
    """A failure category: `test(measures, thresholds)` is True (n,) where it applies. Checked
    in declaration order after "simulation unhealthy"; the first that applies wins."""

    name: str
    description: str
    test: Callable[[Mapping[str, np.ndarray], Mapping[str, float]], np.ndarray]
