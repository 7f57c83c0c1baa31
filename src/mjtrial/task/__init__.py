"""The task interface: what a researcher writes for an experiment of their own, in one Python
file beside its model.

The vocabulary is dm_control's `Task` (initialize the episode, act before a step, observe) and
gymnasium's `reset(seed=...)`, in declarations rather than callbacks where mjtrial must read them
(to build the config schema, the states table, the preflight checks):

- `model`: the MJCF file, relative to the task file;
- `state_parameters`: the randomized initial state, each `StateParameter` with its unit, default
  range and how it is applied (`BodyMass`, `JointPosition`, `JointVelocity`, a `Custom`
  function, `DISTURBANCE`: read by the closed-loop controller's `pushes`, or `GOAL`: a goal no
  model element holds, read by an observation or by the success test); the states
  table's columns are their names, drawn in this order;
- `protocol_parameters`: what conditions, sweeps and variants may set, with types and bounds;
- `controller`: `OpenLoop` (a control sequence per condition, run by `mujoco.rollout`) or
  `ClosedLoop` (a policy called on a batch of observations at the control rate, whose output
  columns drive actuators' ctrl and mocap bodies' targets: `Control`, `MocapAction`);
- `observations`: each with its real-world source, or privileged (`source=None`): a joint's
  position, a state parameter's value, a `<sensor>` of the model (`Observation.sensor`), each
  through an optional `ObservationModel` (noise, bias, quantization, dropped readings);
- `success`, `measures` and the ordered `failure_categories` with their `thresholds`.

A task is loaded from a file path (`tasks/<name>/task.py`, which defines `TASK`) or an importable
name (`package.module`), or offered by an installed package through the entry point group
`mjtrial.tasks`. Nothing in the package names a task's elements.
"""

from mjtrial.closest_calls import Margin
from mjtrial.task.actions import Control, MocapAction
from mjtrial.task.appliers import (
    DISTURBANCE,
    EPISODE_SETUP,
    GOAL,
    BodyMass,
    Custom,
    Disturbance,
    Goal,
    JointPosition,
    JointVelocity,
    MocapPosition,
    ModelValue,
    ReadBySetup,
    Rotation,
)
from mjtrial.task.bound import BoundTask
from mjtrial.task.declare import (
    ENGINE_MEASURES,
    FAILURE_CATEGORY,
    NONFINITE,
    NONFINITE_ACTION,
    STEPS_SIMULATED,
    UNHEALTHY,
    WARNING,
    ClosedLoop,
    Episodes,
    FailureCategory,
    Measure,
    ModelCheckError,
    NotAFunctionError,
    Observation,
    OpenLoop,
    ProtocolParameter,
    Series,
    SeriesRead,
    StateParameter,
    TaskError,
    Threshold,
)
from mjtrial.task.definition import Task, call, expect_rows
from mjtrial.task.load import ENTRY_POINT_GROUP, load_task, task_files
from mjtrial.task.observation_model import ObservationModel

from mjtrial.task import address  # isort: skip - after the package's names (declare uses it)

__all__ = [
    "DISTURBANCE",
    "ENGINE_MEASURES",
    "EPISODE_SETUP",
    "GOAL",
    "ENTRY_POINT_GROUP",
    "FAILURE_CATEGORY",
    "NONFINITE",
    "NONFINITE_ACTION",
    "STEPS_SIMULATED",
    "UNHEALTHY",
    "WARNING",
    "BodyMass",
    "BoundTask",
    "ClosedLoop",
    "Control",
    "Custom",
    "Disturbance",
    "Goal",
    "Episodes",
    "FailureCategory",
    "JointPosition",
    "JointVelocity",
    "Margin",
    "Measure",
    "MocapAction",
    "MocapPosition",
    "Rotation",
    "ModelValue",
    "ModelCheckError",
    "Observation",
    "NotAFunctionError",
    "ObservationModel",
    "OpenLoop",
    "ProtocolParameter",
    "ReadBySetup",
    "Series",
    "SeriesRead",
    "StateParameter",
    "Task",
    "TaskError",
    "Threshold",
    "address",
    "call",
    "expect_rows",
    "load_task",
    "task_files",
]


def __getattr__(name: str) -> object:
    """`mjtrial.task.STATE_QPOS`, which tasks imported before it moved: deprecated."""
    if name == "STATE_QPOS":
        import warnings  # only a deprecated name's reader needs these

        from mjtrial.sim.physics import STATE_QPOS  # physics is imported already: no cost

        warnings.warn(
            "mjtrial.task.STATE_QPOS is deprecated; import mjtrial.sim.physics.STATE_QPOS",
            DeprecationWarning,
            stacklevel=2,
        )
        return STATE_QPOS
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
