"""A task with its model loaded and every name it reads resolved: what the engine runs."""

from __future__ import annotations

import copy
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import Any

import mujoco
import numpy as np

from mjtrial.physics import FULLPHYSICS, ModelError, load_model
from mjtrial.task.declare import ModelCheckError, SeriesRead, TaskError, _element
from mjtrial.task.definition import Task

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
                model = load_model(task.model)
            except ModelError as err:
                raise TaskError(str(err)) from None
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
        parameters = [p.name for p in task.state_parameters]
        for o in task.observations:
            if o.parameter is not None:
                if o.parameter not in parameters:
                    raise TaskError(
                        f"{where}: observation {o.name!r}: expected one of the state "
                        f"parameters {parameters}, got {o.parameter!r}"
                    )
                continue
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

    @property
    def reuses_models(self) -> bool:
        """Whether an episode's model copy can serve another episode: every model parameter
        sets its value whatever was there (`BodyMass`, `ModelValue`; a `Custom` may not), so
        applying the next episode's values and recomputing the constants gives the model a
        fresh copy would. A copy of a model with textures costs 16 ms (dm_control's reacher)."""
        return all(
            getattr(p.apply, "sets", False)
            for p in self.task.state_parameters
            if p.apply.stage == "model"
        )

    def episode(
        self,
        values: Mapping[str, float],
        *,
        scratch: mujoco.MjData,
        model: mujoco.MjModel | None = None,
    ) -> tuple[mujoco.MjModel, np.ndarray]:
        """The episode's own model and its mjSTATE_FULLPHYSICS initial state.

        Model parameters are applied to a copy of the model (`model`, a copy of an earlier
        episode's that this one may reuse when `reuses_models`, else a fresh one), in
        declaration order, then its constants recomputed; the copy is reset to the task's
        keyframe (or qpos0), then the initial parameters are applied in declaration order.
        """
        params = list(zip(self.task.state_parameters, self.appliers, strict=True))
        own = model
        model = self.model
        if any(p.apply.stage == "model" for p, _ in params):
            model = own if own is not None and self.reuses_models else copy.copy(self.model)
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

    def observer(
        self, names: tuple[str, ...], values: Mapping[str, np.ndarray] | None = None
    ) -> Callable[[np.ndarray], np.ndarray]:
        """The observations `names`, side by side: (n, nstate) -> (n, total size).

        `values` are the batch's state parameter values, state parameter -> (n,), in the
        batch's row order: what an episode-value observation reads."""
        declared = {o.name: o for o in self.task.observations}

        def read(name: str) -> Callable[[np.ndarray], np.ndarray]:
            parameter = declared[name].parameter
            if parameter is None:
                return self.observe[name]
            column = np.asarray((values or {})[parameter], dtype=np.float64)[:, None]
            return lambda states: column

        reads = [read(n) for n in names]
        return lambda states: np.concatenate([r(states) for r in reads], axis=1)
