"""The task interface: what a researcher writes for an experiment of their own, in one Python
file beside its model.

The vocabulary is dm_control's `Task` (initialize the episode, act before a step, observe) and
gymnasium's `reset(seed=...)`, in declarations rather than callbacks where mjtrial must read them
(to build the config schema, the states table, the preflight checks):

- `model`: the MJCF file, relative to the task file;
- `state_parameters`: the randomized initial state, each `StateParameter` with its unit, default
  range and how it is applied (`BodyMass`, `JointPosition`, `JointVelocity`, a `Custom`
  function, or `DISTURBANCE`: read by the closed-loop controller's `pushes`); the states
  table's columns are their names, drawn in this order;
- `protocol_parameters`: what conditions, sweeps and variants may set, with types and bounds;
- `controller`: `OpenLoop` (a control sequence per condition, run by `mujoco.rollout`) or
  `ClosedLoop` (a policy called on a batch of observations at the control rate);
- `observations`: each with its real-world source, or privileged (`source=None`);
- `success`, `measures` and the ordered `failure_categories` with their `thresholds`.

A task is loaded from a file path (`tasks/<name>/task.py`, which defines `TASK`) or an importable
name (`package.module`), or offered by an installed package through the entry point group
`mjtrial.tasks`. Nothing in the package names a task's elements.
"""

from __future__ import annotations

import copy
import importlib
import importlib.metadata
import importlib.util
import os
import sys
import threading
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import mujoco
import numpy as np

from mjtrial.closed_loop import BatchPolicy, Pushes, Timing
from mjtrial.closest_calls import Margin
from mjtrial.physics import FULLPHYSICS, STATE_QPOS

ENTRY_POINT_GROUP = "mjtrial.tasks"

# One task import at a time: Snakemake's in-process jobs are threads sharing `sys.modules`.
_IMPORT_LOCK = threading.RLock()
UNHEALTHY = "simulation unhealthy"  # the first failure category of every task


class TaskError(ValueError):
    """A task file that cannot be loaded, or whose declarations or functions are wrong."""


class ModelCheckError(TaskError):
    """The task's `check_model` refused the model; `problem` says why, without the file."""

    def __init__(self, model: Path, problem: str) -> None:
        super().__init__(f"{model}: {problem}")
        self.problem = problem


# --------------------------------------------------------------------------------------------
# State parameters and how each is applied
# --------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class BodyMass:
    """Sets a body's mass (inertia as compiled); constants are recomputed (`mj_setConst`)."""

    body: str
    stage = "model"

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


@dataclass(frozen=True)
class StateParameter:
    """One column of the states table: drawn uniformly in [low, high] (config `states.ranges`
    may change the range), then applied to each episode."""

    name: str
    unit: str
    low: float
    high: float
    apply: BodyMass | JointPosition | JointVelocity | Custom | Disturbance
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


@dataclass(frozen=True)
class Observation:
    """A quantity the controller may read: `read(model)` gives a function from a batch of
    mjSTATE_FULLPHYSICS rows (n, nstate) to (n, size) values. `source` names the real sensor
    it stands for (encoder, IMU, camera pose estimate); None marks it privileged: the
    simulator knows it, a robot would not."""

    name: str
    source: str | None
    read: Callable[[mujoco.MjModel], Callable[[np.ndarray], np.ndarray]]
    size: int = 1

    @classmethod
    def joint_position(cls, name: str, joint: str, *, source: str | None) -> Observation:
        def read(model: mujoco.MjModel) -> Callable[[np.ndarray], np.ndarray]:
            adr = model.jnt_qposadr[_element(model, mujoco.mjtObj.mjOBJ_JOINT, joint)]
            column = STATE_QPOS + adr
            return lambda states: states[:, column : column + 1]

        return cls(name, source, read)

    @classmethod
    def joint_velocity(cls, name: str, joint: str, *, source: str | None) -> Observation:
        def read(model: mujoco.MjModel) -> Callable[[np.ndarray], np.ndarray]:
            adr = model.jnt_dofadr[_element(model, mujoco.mjtObj.mjOBJ_JOINT, joint)]
            column = STATE_QPOS + model.nq + adr
            return lambda states: states[:, column : column + 1]

        return cls(name, source, read)


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
    """

    policy: Callable[[mujoco.MjModel, Mapping[str, float]], BatchPolicy]
    observations: tuple[str, ...]
    timing: Callable[[mujoco.MjModel, Mapping[str, float]], Timing]
    pushes: Callable[[mujoco.MjModel, Mapping[str, np.ndarray]], Pushes] | None = None


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
NONFINITE = Measure("nonfinite", "", "the state went NaN or infinite")
WARNING = Measure("warning", "", "the MuJoCo warnings that stopped the episode, by name")
FAILURE_CATEGORY = Measure("failure_category", "", "the first failure category that applies")
ENGINE_MEASURES = (STEPS_SIMULATED, NONFINITE, WARNING, FAILURE_CATEGORY)


@dataclass(frozen=True)
class Episodes:
    """What a task's outcome functions read about a batch of finished episodes.

    Attributes:
      model: the nominal model of the condition.
      params: the condition's protocol parameters (defaults filled in).
      physics: (n, n_steps, nstate) mjSTATE_FULLPHYSICS after each step.
      sensordata: (n, n_steps, nsensordata) sensor values after each step.
      healthy: (n,) False where a MuJoCo warning froze the episode or it went non-finite.
      ctrl: (n, n_steps, nu) the ctrl applied before each step (open loop: one sequence for
        every episode, broadcast).
    """

    model: mujoco.MjModel
    params: Mapping[str, float]
    physics: np.ndarray
    sensordata: np.ndarray
    healthy: np.ndarray
    ctrl: np.ndarray


@dataclass(frozen=True)
class FailureCategory:
    """A failure category: `test(measures, thresholds)` is True (n,) where it applies. Checked
    in declaration order after "simulation unhealthy"; the first that applies wins."""

    name: str
    description: str
    test: Callable[[Mapping[str, np.ndarray], Mapping[str, float]], np.ndarray]


@dataclass(frozen=True)
class Task:
    """An experiment's own parts (see the module's docstring). `measure(episodes)` returns
    every `Measure` by name, plus any other arrays the categories' tests read."""

    name: str
    title: str  # a noun phrase for reports: "a block pushed to a line"
    model: Path  # resolved against the task file's folder at load
    state_parameters: tuple[StateParameter, ...]
    protocol_parameters: tuple[ProtocolParameter, ...]
    controller: OpenLoop | ClosedLoop
    success: Callable[[Episodes], np.ndarray]
    measure: Callable[[Episodes], Mapping[str, np.ndarray]]
    measures: tuple[Measure, ...] = ()
    failure_categories: tuple[FailureCategory, ...] = ()
    thresholds: tuple[Threshold, ...] = ()
    observations: tuple[Observation, ...] = ()
    series: tuple[Series, ...] = ()
    # `check_condition(model, params)`: (parameter, expectation) for each problem of a
    # condition on this model, before any episode runs (a hold shorter than one step); a
    # problem named by something other than a protocol parameter is the model's timestep's.
    check_condition: Callable[[mujoco.MjModel, Mapping[str, float]], Any] | None = None
    # `check_model(model)` raises, saying what the model lacks, before anything is resolved.
    check_model: Callable[[mujoco.MjModel], None] | None = None
    keyframe: int | None = None  # the reset pose (None: the model's qpos0)
    # The report's and the manifest's words (the package has none of a task's own):
    success_text: str = ""  # when an episode succeeds, a sentence's end ("the block's centre ...")
    nominal_text: str = ""  # the nominal state in words (default: each parameter's value)
    limitations: tuple[str, ...] = ()  # what the experiment does not show, one point each
    trace: str | None = None  # the series drawn for sample episodes (default: the first)
    # `trace_marks(model, params)`: label -> time (s) of a protocol event drawn on the traces.
    trace_marks: Callable[[mujoco.MjModel, Mapping[str, float]], Mapping[str, float]] | None = None
    trace_levels: tuple[tuple[str, float], ...] = ()  # (label, value) lines across the traces
    margin: Margin | None = None  # the success test's margin (the closest calls; None: none)
    source: Path | None = field(default=None, compare=False)  # the task file, set at load

    @property
    def state_columns(self) -> tuple[str, ...]:
        return ("state_id", *(p.name for p in self.state_parameters))

    @property
    def table_measures(self) -> tuple[Measure, ...]:
        """The rollout table's columns after `state_id` and `success`: the task's measures, with
        the engine's (`ENGINE_MEASURES`) where the task placed them, else after its own."""
        placed = {m.name for m in self.measures}
        return (*self.measures, *(m for m in ENGINE_MEASURES if m.name not in placed))

    @property
    def own_measures(self) -> tuple[Measure, ...]:
        """The measures the task's `measure` function computes (not the engine's)."""
        engine = {m.name for m in ENGINE_MEASURES}
        return tuple(m for m in self.measures if m.name not in engine)

    def parameters(self, condition: Mapping[str, float]) -> dict[str, float]:
        """The protocol parameters of a condition, defaults filled in."""
        return {p.name: float(condition.get(p.name, p.default)) for p in self.protocol_parameters}

    def config_schema(self, schema: Mapping[str, Any]) -> dict[str, Any]:
        """The config's JSON schema with what the task declares: each condition's protocol
        parameters, the failure taxonomy's thresholds, the parameters a sweep may vary and the
        state parameters analysis bands may name (`<name>`, or `abs_<name>` for magnitudes)."""
        out = copy.deepcopy(dict(schema))
        props = out["properties"]
        condition = props["conditions"]["additionalProperties"]
        condition["properties"] = {p.name: p.schema() for p in self.protocol_parameters}
        condition["required"] = [p.name for p in self.protocol_parameters if p.required]
        taxonomy = props["failure_taxonomy"]
        taxonomy["properties"] = {t.name: t.schema() for t in self.thresholds}
        taxonomy["required"] = [t.name for t in self.thresholds]
        props["sweep"]["properties"]["parameter"]["enum"] = [
            p.name for p in self.protocol_parameters
        ]
        bands = props["analysis"]["properties"]["bands"]
        bands["properties"] = {
            f"{prefix}{p.name}": {
                "$ref": "#/$defs/edges",
                "description": f"{prefix.replace('abs_', '|')}{p.name}"
                f"{'|' if prefix else ''} band edges, {p.unit}",
            }
            for p in self.state_parameters
            for prefix in ("", "abs_")
        }
        return out

    def category_names(self) -> tuple[str, ...]:
        return (UNHEALTHY, *(c.name for c in self.failure_categories))

    @property
    def nominal_description(self) -> str:
        """The nominal state in words: the task's, or each state parameter's nominal value."""
        return self.nominal_text or ", ".join(
            f"{p.name} {p.nominal_value:g} {p.unit}".rstrip() for p in self.state_parameters
        )

    @property
    def trace_series(self) -> Series | None:
        """The series the report draws for its sample episodes."""
        if self.trace is None:
            return self.series[0] if self.series else None
        return next(s for s in self.series if s.name == self.trace)

    def unit_of(self, name: str) -> str:
        """The unit of a state or protocol parameter, threshold or measure (`abs_<name>` too)."""
        name = name.removeprefix("abs_")
        for p in (*self.state_parameters, *self.protocol_parameters, *self.thresholds):
            if p.name == name:
                return p.unit
        for m in self.table_measures:
            if m.name == name:
                return m.unit
        return ""

    def condition_values(self, condition: Mapping[str, Any]) -> dict[str, float | int]:
        """The protocol parameters a condition sets, as numbers (integers for integer ones)."""
        kinds = {p.name: p for p in self.protocol_parameters}
        return {
            k: int(v) if kinds[k].integer else float(v) for k, v in condition.items() if k in kinds
        }


def expect_rows(task: Task, function: str, value: Any, n: int, *, dtype=None) -> None:
    """Refuse (one line) what a task function returned unless it is one value per episode."""
    where, shape = task.source or task.name, np.shape(value)
    if shape != (n,):
        raise TaskError(
            f"{where}: {function}: expected an array of shape ({n},), one value per episode, "
            f"got shape {shape}"
        )
    if dtype is bool and np.asarray(value).dtype != bool:
        raise TaskError(f"{where}: {function}: expected booleans, got {np.asarray(value).dtype}")


def call(task: Task, function: str, fn: Callable[..., Any], *args: Any, **kwargs: Any) -> Any:
    """`fn(*args, **kwargs)`, a function of the task's: an exception in it becomes a one-line
    `TaskError` naming the task file and the function."""
    try:
        return fn(*args, **kwargs)
    except TaskError:
        raise
    except Exception as err:  # noqa: BLE001 - the user's code: one line naming it
        where = task.source or task.name
        raise TaskError(f"{where}: {function} raised {type(err).__name__}: {err}") from None


# --------------------------------------------------------------------------------------------
# Loading
# --------------------------------------------------------------------------------------------


def _element(model: mujoco.MjModel, kind: mujoco.mjtObj, name: str) -> int:
    index = mujoco.mj_name2id(model, kind, name)
    if index < 0:
        noun = kind.name.removeprefix("mjOBJ_").lower()
        raise TaskError(f"expected a {noun} named {name!r} in the model")
    return index


def _from_file(path: Path) -> Task:
    """Import a task file afresh. In a folder with an `__init__.py` (a task package, whose
    siblings it imports relatively: `from .protocol import ...`), the folder is imported as a
    package of a name unique to its path, so two copies of one task never share modules and an
    edit is always seen; else the file alone is imported."""
    name = f"mjtrial_task_{abs(hash(path.resolve()))}"
    with _IMPORT_LOCK:
        try:
            if (path.parent / "__init__.py").is_file():
                for cached in [m for m in sys.modules if m == name or m.startswith(f"{name}.")]:
                    del sys.modules[cached]
                package_spec = importlib.util.spec_from_file_location(
                    name, path.parent / "__init__.py", submodule_search_locations=[str(path.parent)]
                )
                package = importlib.util.module_from_spec(package_spec)
                sys.modules[name] = package
                package_spec.loader.exec_module(package)
                name = f"{name}.{path.stem}"
            spec = importlib.util.spec_from_file_location(name, path)
            if spec is None or spec.loader is None:
                raise TaskError(f"{path}: not a Python file")
            module = importlib.util.module_from_spec(spec)
            sys.modules[name] = module
            spec.loader.exec_module(module)
        except TaskError:
            raise
        except Exception as err:  # noqa: BLE001 - any error in the user's file is one line
            sys.modules.pop(name, None)
            raise TaskError(f"{path}: the task file raised {type(err).__name__}: {err}") from None
    return _task_of(module, str(path), path.parent)


def task_files(task_file: Path) -> list[Path]:
    """What stamps record of a task named by path and an edit reruns: every file of its folder
    and below (data the task reads included), less caches and hidden files, sorted."""
    folder = Path(task_file).parent
    if (folder / "Snakefile").exists():
        raise TaskError(f"{task_file}: expected a folder of its own (its files are its inputs)")
    files = {p.relative_to(folder) for p in folder.rglob("*") if p.is_file()}
    cached = {p for p in files if any(x == "__pycache__" or x[0] == "." for x in p.parts)}
    return sorted(folder / p for p in files - cached)


def _task_of(module: Any, where: str, folder: Path) -> Task:
    task = getattr(module, "TASK", None)
    if not isinstance(task, Task):
        raise TaskError(f"{where}: expected a module-level TASK = mjtrial.task.Task(...)")
    model = Path(task.model)
    model = Path(os.path.normpath(model if model.is_absolute() else folder / model))
    source = Path(module.__file__) if getattr(module, "__file__", None) else None
    if not task.series:
        raise TaskError(f"{source or where}: series: expected at least one Series to record")
    names = [s.name for s in task.series]
    if task.trace is not None and task.trace not in names:
        raise TaskError(f"{source or where}: trace: expected one of the series {names}")
    measures = [m.name for m in task.measures]
    if task.margin is not None and task.margin.measure not in measures:
        raise TaskError(
            f"{source or where}: margin: expected the name of one of the measures {measures}, "
            f"got {task.margin.measure!r}"
        )
    return replace(task, model=model, source=source)


def load_task(reference: str | Path, *, repo_root: Path = Path(".")) -> Task:
    """The task a config names: a `.py` path (relative to `repo_root`), an entry point name of
    the group `mjtrial.tasks`, or an importable module name defining `TASK`."""
    text = str(reference)
    if text.endswith(".py"):
        path = Path(text) if Path(text).is_absolute() else Path(repo_root) / text
        if not path.is_file():
            raise TaskError(f"{text}: task file not found")
        task_files(path)
        return _from_file(path)
    for entry in importlib.metadata.entry_points(group=ENTRY_POINT_GROUP):
        if entry.name == text:
            module = entry.load()
            return _task_of(module, f"entry point {text}", Path(module.__file__).parent)
    try:
        module = importlib.import_module(text)
    except ImportError as err:
        raise TaskError(
            f"{text}: no task file, entry point ({ENTRY_POINT_GROUP}) or module of that name "
            f"({err})"
        ) from None
    return _task_of(module, text, Path(module.__file__).parent)


# --------------------------------------------------------------------------------------------
# Episodes' models and initial states
# --------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class BoundTask:
    """A task with its model loaded and every name resolved: what the engine runs."""

    task: Task
    model: mujoco.MjModel
    appliers: tuple[Any, ...]  # per state parameter: its bound apply function, or None
    observe: Mapping[str, Callable[[np.ndarray], np.ndarray]]
    series: tuple[SeriesRead, ...] = ()  # per `task.series`: its bound read

    @classmethod
    def of(cls, task: Task, model: mujoco.MjModel | None = None) -> BoundTask:
        """Load the model (unless given) and resolve the names the task reads; a missing element
        is a `TaskError` naming the task file and the parameter or observation."""
        where = task.source or task.name
        if model is None:
            try:
                model = mujoco.MjModel.from_xml_path(str(task.model))
            except ValueError as err:
                message = " ".join(str(err).split())
                raise TaskError(
                    f"{task.model}: MuJoCo could not compile the model: {message}"
                ) from None
        if task.check_model is not None:
            try:
                task.check_model(model)
            except Exception as err:  # noqa: BLE001 - the task's words for what is missing
                raise ModelCheckError(task.model, str(err)) from None
        appliers, observe, series = [], {}, []
        for p in task.state_parameters:
            try:
                appliers.append(p.apply.bind(model))
            except TaskError as err:
                raise TaskError(f"{where}: state parameter {p.name!r}: {err}") from None
        for o in task.observations:
            try:
                observe[o.name] = o.read(model)
            except TaskError as err:
                raise TaskError(f"{where}: observation {o.name!r}: {err}") from None
        for x in task.series:
            try:
                _element(model, mujoco.mjtObj.mjOBJ_BODY, x.body)
                series.append(x.read(model))
            except TaskError as err:
                raise TaskError(f"{where}: series {x.name!r}: {err}") from None
        return cls(task, model, tuple(appliers), observe, tuple(series))

    def episode(
        self, values: Mapping[str, float], *, scratch: mujoco.MjData
    ) -> tuple[mujoco.MjModel, np.ndarray]:
        """The episode's own model and its mjSTATE_FULLPHYSICS initial state.

        Model parameters are applied to a copy of the model, in declaration order, then its
        constants recomputed; the copy is reset to the task's keyframe (or qpos0), then the
        initial parameters are applied in declaration order.
        """
        params = list(zip(self.task.state_parameters, self.appliers, strict=True))
        model = self.model
        if any(p.apply.stage == "model" for p, _ in params):
            model = copy.copy(self.model)
            for p, apply in params:
                if p.apply.stage == "model":
                    apply(model, scratch, values[p.name])
            mujoco.mj_setConst(model, scratch)
        if self.task.keyframe is None:
            mujoco.mj_resetData(model, scratch)
        else:
            mujoco.mj_resetDataKeyframe(model, scratch, self.task.keyframe)
        for p, apply in params:
            if p.apply.stage == "initial":
                apply(model, scratch, values[p.name])
        state = np.empty(mujoco.mj_stateSize(model, FULLPHYSICS))
        mujoco.mj_getState(model, scratch, state, FULLPHYSICS)
        return model, state

    def observer(self, names: tuple[str, ...]) -> Callable[[np.ndarray], np.ndarray]:
        """The observations `names`, side by side: (n, nstate) -> (n, total size)."""
        reads = [self.observe[n] for n in names]
        return lambda states: np.concatenate([r(states) for r in reads], axis=1)
