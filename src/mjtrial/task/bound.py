"""A task with its model loaded and every name it reads resolved: what the engine runs."""

from __future__ import annotations

import copy
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import mujoco
import numpy as np

from mjtrial.sim.actuation import Actuation
from mjtrial.sim.closed_loop import Observer
from mjtrial.sim.physics import FULLPHYSICS, ModelError, load_model
from mjtrial.task.actions import bind_actions
from mjtrial.task.declare import (
    ClosedLoop,
    ModelCheckError,
    Observation,
    SeriesRead,
    TaskError,
    _element,
)
from mjtrial.task.definition import Task, call
from mjtrial.task.observation_model import with_errors
from mjtrial.task.poses import PoseError, PoseProbe

# --------------------------------------------------------------------------------------------
# Episodes' models and initial states
# --------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class BoundTask:
    """A task with its model loaded and every name resolved: what the engine runs."""

    task: Task
    model: mujoco.MjModel
    appliers: tuple[Any, ...]  # per state parameter: its bound apply function, or None
    # per observation of the physics state: its read; of a sensor: its sensordata columns
    observe: Mapping[str, Callable[[np.ndarray], np.ndarray] | slice]
    series: tuple[SeriesRead, ...] = ()  # per `task.series`: its bound read
    actuation: Actuation | None = None  # a closed-loop policy's output columns, bound

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
            if p.apply.stage == "setup" and task.episode_setup is None:
                raise TaskError(
                    f"{where}: state parameter {p.name!r}: EPISODE_SETUP expected the task to "
                    "declare an episode_setup that reads it"
                )
            try:
                appliers.append(p.apply.bind(model))
            except TaskError as err:
                raise TaskError(f"{where}: state parameter {p.name!r}: {err}") from None
        parameters = [p.name for p in task.state_parameters]
        protocol = [p.name for p in task.protocol_parameters]
        for o in task.observations:
            for role, name in (o.errors.parameters() if o.errors else {}).items():
                if name not in protocol:
                    raise TaskError(
                        f"{where}: observation {o.name!r}: {role}: expected one of the "
                        f"protocol parameters {protocol}, got {name!r}"
                    )
            if o.parameter is not None:
                if o.parameter not in parameters:
                    raise TaskError(
                        f"{where}: observation {o.name!r}: expected one of the state "
                        f"parameters {parameters}, got {o.parameter!r}"
                    )
                continue
            try:
                if o.pose is not None:
                    observe[o.name] = o.pose.bind(model)  # read on each episode's model
                else:
                    observe[o.name] = _sensor(model, o) if o.sensor_name else o.read(model)
            except (TaskError, PoseError) as err:
                raise TaskError(f"{where}: observation {o.name!r}: {err}") from None
        for x in task.series:
            try:
                _element(model, mujoco.mjtObj.mjOBJ_BODY, x.body)
                series.append(x.read(model))
            except TaskError as err:
                raise TaskError(f"{where}: series {x.name!r}: {err}") from None
        actuation = None
        if isinstance(task.controller, ClosedLoop):
            try:
                actuation = bind_actions(model, task.controller.actions)
            except TaskError as err:
                raise TaskError(f"{task.controller.source or where}: {err}") from None
        return cls(task, model, tuple(appliers), observe, tuple(series), actuation)

    @property
    def reuses_models(self) -> bool:
        """Whether an episode's model copy can serve another episode: every model parameter
        sets its value whatever was there (`BodyMass`, `ModelValue`; a `Custom` may not), so
        applying the next episode's values and recomputing the constants gives the model a
        fresh copy would. A copy of a model with textures costs 16 ms (dm_control's reacher).
        A task's `episode_setup` may change any field, so its episodes get fresh copies."""
        return not self.setup_copies and all(
            getattr(p.apply, "sets", False)
            for p in self.task.state_parameters
            if p.apply.stage == "model"
        )

    @property
    def setup_copies(self) -> bool:
        """Whether each episode needs a model copy for the task's `episode_setup`."""
        return self.task.episode_setup is not None and self.task.setup_edits_model

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
        keyframe (or qpos0), the task's `episode_setup` runs, then the initial parameters are
        applied in declaration order. The mocap poses the setup leaves are kept in the copy's
        `body_pos` / `body_quat`, from which every reset (`mujoco.rollout`'s) takes them.
        """
        params = list(zip(self.task.state_parameters, self.appliers, strict=True))
        own = model
        model = self.model
        setup = self.task.episode_setup
        edits_model = any(p.apply.stage == "model" for p, _ in params)
        if edits_model or self.setup_copies:
            model = own if own is not None and self.reuses_models else copy.copy(self.model)
        if edits_model:
            for p, apply in params:
                if p.apply.stage == "model":
                    apply(model, scratch, values[p.name])
            mujoco.mj_setConst(model, scratch)
        if self.task.keyframe is None:
            mujoco.mj_resetData(model, scratch)
        else:
            mujoco.mj_resetDataKeyframe(model, scratch, self.task.keyframe)
        if setup is not None:
            own_values = {p.name: float(values[p.name]) for p, _ in params}
            call(self.task, "episode_setup", setup, model, scratch, own_values)
            bodies = np.flatnonzero(model.body_mocapid >= 0)
            model.body_pos[bodies] = scratch.mocap_pos[model.body_mocapid[bodies]]
            model.body_quat[bodies] = scratch.mocap_quat[model.body_mocapid[bodies]]
        for p, apply in params:
            if p.apply.stage == "initial":
                apply(model, scratch, values[p.name])
        state = np.empty(mujoco.mj_stateSize(model, FULLPHYSICS))
        mujoco.mj_getState(model, scratch, state, FULLPHYSICS)
        return model, state

    def observer(
        self,
        names: tuple[str, ...],
        values: Mapping[str, np.ndarray] | None = None,
        *,
        params: Mapping[str, float] | None = None,
        n_controls: int | None = None,
        models: Sequence[mujoco.MjModel] | None = None,
    ) -> Observer:
        """The observations `names`, side by side: what the policy is given at each control
        instant, (n, total size).

        Args:
          names: the observations, in the policy's order.
          values: the batch's state parameter values, state parameter -> (n,), in the batch's
            row order: what an episode-value observation reads, and the seed of each episode's
            observation errors (`mjtrial.task.observation_model`).
          params: the condition's protocol parameters (default: the defaults): the values of
            the observation errors' parameters.
          n_controls: control instants per episode (needed when an observation has errors).
          models: each row's own model (`episode`), on which a pose observation is computed
            (`mjtrial.task.poses`); needed for one when a state parameter edits the model.
        """
        declared = {o.name: o for o in self.task.observations}
        params = self.task.parameters(params or {})
        where = self.task.source or self.task.name

        posed = [n for n in dict.fromkeys(names) if declared[n].pose is not None]
        probe = self._pose_probe(posed, models) if posed else None

        def read(name: str) -> Callable[[int, np.ndarray, np.ndarray | None], np.ndarray]:
            o = declared[name]
            if o.pose is not None:
                j = posed.index(name)
                true = lambda k, states, sensors: probe(k, states)[j]  # noqa: E731
            elif o.parameter is not None:
                column = np.asarray((values or {})[o.parameter], dtype=np.float64)[:, None]
                true = lambda k, states, sensors: column  # noqa: E731
            elif o.sensor_name is not None:
                columns = self.observe[name]
                true = lambda k, states, sensors: sensors[:, columns]  # noqa: E731
            else:
                of_states = self.observe[name]
                true = lambda k, states, sensors: of_states(states)  # noqa: E731
            if o.errors is None:
                return true
            problem = o.errors.problem(params)
            if problem is not None:
                raise TaskError(f"{where}: observation {name!r}: {problem}")
            if values is None or n_controls is None:
                raise ValueError(f"observation {name!r} has errors: give values and n_controls")
            rows = np.stack([np.asarray(values[p.name]) for p in self.task.state_parameters], 1)
            return with_errors(
                true, o.errors, params, name=name, values=rows, n_controls=n_controls
            )

        reads = [read(n) for n in names]
        sensed = any(declared[n].sensor_name is not None for n in names)
        return Observer(
            lambda k, states, sensors: np.concatenate(
                [r(k, states, sensors) for r in reads], axis=1
            ),
            sensed=sensed,
        )

    def _pose_probe(
        self, posed: list[str], models: Sequence[mujoco.MjModel] | None
    ) -> Callable[[int, np.ndarray], list[np.ndarray]]:
        """(k, states) -> each pose observation's (n, size) values, on each row's model."""
        reads = [self.observe[n] for n in posed]
        if models is not None:
            return PoseProbe(models, reads).values
        if any(p.apply.stage == "model" for p in self.task.state_parameters):
            raise ValueError(f"observation {posed[0]!r} is a pose: give each row's model (models)")
        probes: dict[int, PoseProbe] = {}  # the nominal model for every row, by batch size

        def values(k: int, states: np.ndarray) -> list[np.ndarray]:
            n = len(states)
            probe = probes.setdefault(n, PoseProbe([self.model] * n, reads))
            return probe.values(k, states)

        return values

    def widths(self, names: Sequence[str]) -> list[int]:
        """The number of columns of each observation `names` (a sensor's dimension)."""
        declared = {o.name: o for o in self.task.observations}
        return [declared[n].columns(self.model) for n in names]


def _sensor(model: mujoco.MjModel, o: Observation) -> slice:
    """The sensordata columns of a sensor observation; a sensor computed from accelerations or
    forces is refused (the module docstring of `mjtrial.sim.closed_loop`)."""
    index = _element(model, mujoco.mjtObj.mjOBJ_SENSOR, o.sensor_name)
    if model.sensor_needstage[index] == mujoco.mjtStage.mjSTAGE_ACC:
        kind = mujoco.mjtSensor(model.sensor_type[index]).name.removeprefix("mjSENS_").lower()
        raise TaskError(
            f"sensor {o.sensor_name!r} ({kind}) is computed from accelerations and forces, which "
            "depend on the control at the measured instant; expected a position or velocity sensor"
        )
    adr = int(model.sensor_adr[index])
    return slice(adr, adr + int(model.sensor_dim[index]))
