"""The `Task` record: an experiment's own parts, and the helpers that call a task's functions
safely (`call`, `expect_rows`).
"""

from __future__ import annotations

import copy
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import mujoco
import numpy as np

from mjtrial.closest_calls import Margin
from mjtrial.task.declare import (
    ENGINE_MEASURES,
    UNHEALTHY,
    ClosedLoop,
    Episodes,
    FailureCategory,
    Measure,
    Observation,
    OpenLoop,
    ProtocolParameter,
    Series,
    StateParameter,
    TaskError,
    Threshold,
)


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
    # `episode_setup(model, data, values)`: a suite's own reset, run on each episode's model
    # copy after the reset to the keyframe and before the "initial" state parameters (values:
    # the episode's state parameter values). It may set model fields (a weld's eq_data), data
    # (qpos, mocap_pos, mocap_quat) and step the physics (`BoundTask.episode`).
    episode_setup: Callable[[mujoco.MjModel, mujoco.MjData, Mapping[str, float]], None] | None = (
        None
    )
    # False: the setup sets the episode's data only (a reset pose, as robosuite's), so every
    # episode runs on the nominal model, no copy each (robosuite's exported Panda scene is 64 MB
    # of meshes).
    # The config check runs the setup on a copy and refuses one that changed the model.
    setup_edits_model: bool = True
    # `valid_state(values)`: (n,) True where a drawn state is allowed (values: state parameter
    # -> (n,)); the others are redrawn from the seed (`mjtrial.design.states.draw_states`).
    valid_state: Callable[[Mapping[str, np.ndarray]], np.ndarray] | None = None
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
        condition["properties"] |= {p.name: p.schema() for p in self.protocol_parameters}
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
                "$ref": "#/$defs/edges" if prefix else "#/$defs/signed_edges",
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
