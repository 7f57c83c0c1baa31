"""The preflight of a task: its code run once on every condition's nominal episode before any
rollout, so a mistake in it is one line naming the task file, the function and what was
expected, and never a traceback in the middle of a run.

Also the course's cheap test of a policy: an observation without a real-world source
(privileged, `Observation.source is None`) is refused unless the config allows it with a reason.
"""

from __future__ import annotations

import copy
import hashlib
from collections.abc import Mapping
from dataclasses import replace

import mujoco
import numpy as np

from mjtrial.sim.closed_loop import PolicyError, check_batch_independence
from mjtrial.sim.engine import iter_batches, low_level_of
from mjtrial.sim.low_level import ControllerError, check_rows_alone
from mjtrial.sim.physics import compiled_sha256, simulated_sha256
from mjtrial.task import (
    BoundTask,
    ClosedLoop,
    Episodes,
    NotAFunctionError,
    OpenLoop,
    Task,
    TaskError,
    call,
    expect_rows,
)


def _where(task: Task) -> str:
    return str(task.source or task.name)


def check_observations(task: Task, allowed: Mapping[str, str]) -> dict[str, str]:
    """The privileged observations the policy reads with the config's allowance (name ->
    reason); raises `TaskError` for an undeclared one, or a privileged one not allowed."""
    controller = task.controller
    if not isinstance(controller, ClosedLoop):
        return {}
    declared = {o.name: o for o in task.observations}
    where = controller.source or _where(task)  # a policy file's contract names its observations
    used: dict[str, str] = {}
    for name in controller.observations:
        if name not in declared:
            raise TaskError(
                f"{where}: the policy reads observation {name!r}, which is not declared "
                f"in observations (declared: {sorted(declared)})"
            )
        if declared[name].source is None:
            if name not in allowed:
                raise TaskError(
                    f"{where}: the policy reads {name!r}, a privileged observation (no "
                    "real-world source); give it its sensor, or allow it in the config's "
                    f"privileged_observations with a reason"
                )
            used[name] = allowed[name]
    return used


def nominal_values(task: Task) -> dict[str, np.ndarray]:
    return {p.name: np.array([p.nominal_value]) for p in task.state_parameters}


def run_task_code(
    bound: BoundTask,
    conditions: Mapping[str, Mapping[str, float]],
    *,
    thresholds: Mapping[str, float],
    allowed_privileged: Mapping[str, str] | None = None,
) -> None:
    """Run the task's code on each condition's nominal episode and check what it returns; then
    check that every state parameter changes the episode. Raises `TaskError` (one line)."""
    task = bound.task
    check_observations(task, allowed_privileged or {})
    episodes = None  # a nominal episode, for what the task's outcome functions read
    for name, condition in conditions.items():
        params = task.parameters(condition)
        controller = task.controller
        if isinstance(controller, OpenLoop):
            ctrl = np.asarray(call(task, "controls", controller.controls, bound.model, params))
            if ctrl.ndim != 2 or ctrl.shape[1] != bound.model.nu:
                raise TaskError(
                    f"{_where(task)}: controls: expected (n_steps, {bound.model.nu}), "
                    f"got {ctrl.shape}"
                )
            if not np.isfinite(ctrl).all():
                raise TaskError(f"{_where(task)}: controls: non-finite values for condition {name}")
        else:
            policy = call(task, "policy", controller.policy, bound.model, params)
            call(task, "timing", controller.timing, bound.model, params)
            # each observation's own number of columns (a `framepos` sensor's 3)
            widths = bound.widths(controller.observations)
            probe = np.random.default_rng(0).normal(size=(4, sum(widths)))
            try:
                check_batch_independence(policy, probe)
            except PolicyError as err:
                raise TaskError(f"{controller.source or _where(task)}: {err}") from None
            except TaskError:  # a policy file's own one line (`PolicyFileError`), its file named
                raise
            except Exception as err:  # noqa: BLE001 - the policy's code, on its input's width
                given = ", ".join(
                    f"{n} {w}" for n, w in zip(controller.observations, widths, strict=True)
                )
                raise TaskError(
                    f"{controller.source or _where(task)}: policy raised {type(err).__name__} on "
                    f"a batch of its observations, {sum(widths)} columns ({given}): {err}"
                ) from None
            make = low_level_of(bound, params)
            if make is not None:
                values = {k: v[0] for k, v in nominal_values(task).items()}
                model, state = bound.episode(values, scratch=mujoco.MjData(bound.model))
                try:
                    check_rows_alone(make, model, state)
                except ControllerError as err:
                    raise TaskError(f"{_where(task)}: {err}") from None
        try:
            batch = next(
                iter_batches(bound, nominal_values(task), condition, thresholds=thresholds)
            )
        except TaskError:  # the policy's too (`iter_batches` names the task file)
            raise
        except Exception as err:  # noqa: BLE001 - an error in the task's functions
            raise TaskError(
                f"{_where(task)}: condition {name}: the nominal episode raised "
                f"{type(err).__name__}: {err}"
            ) from None
        _check_outcome(task, batch.episodes, thresholds)
        episodes = batch.episodes
    _check_parameters_applied(bound, episodes)
    check_setup_is_a_function(bound)
    _check_setup_leaves_model(bound)


def _check_setup_leaves_model(bound: BoundTask) -> None:
    """A task that says its `episode_setup` sets data only (`setup_edits_model=False`) has its
    episodes share the nominal model: refuse a setup that changes it, run on a copy."""
    task = bound.task
    if task.episode_setup is None or task.setup_edits_model:
        return
    copied = copy.copy(bound.model)
    data = mujoco.MjData(copied)
    values = {k: float(v[0]) for k, v in nominal_values(task).items()}
    call(task, "episode_setup", task.episode_setup, copied, data, values)
    if compiled_sha256(copied) != compiled_sha256(bound.model):
        raise TaskError(
            f"{_where(task)}: episode_setup changed the model, where the task says it sets the "
            "episode's data only (setup_edits_model=False): every episode would run on the "
            "changed nominal model; declare setup_edits_model=True"
        )


def _check_outcome(task: Task, episodes: Episodes, thresholds: Mapping[str, float]) -> None:
    n = len(episodes.physics)
    expect_rows(task, "success", call(task, "success", task.success, episodes), n, dtype=bool)
    measures = call(task, "measure", task.measure, episodes)
    for m in task.own_measures:
        if m.name not in measures:
            raise TaskError(f"{_where(task)}: measure: expected a value for {m.name!r}")
        expect_rows(task, f"measure[{m.name!r}]", measures[m.name], n)
    for c in task.failure_categories:
        hit = call(task, f"failure category {c.name!r}", c.test, measures, thresholds)
        expect_rows(task, f"failure category {c.name!r}", hit, n, dtype=bool)


def nominal_episode_sha256(bound: BoundTask) -> str:
    """The sha256 of what the nominal episode's simulation depends on: its own model and its
    initial state, each state parameter at its nominal value (`physics.simulated_sha256`). Two
    models with equal hashes run the nominal episode alike: an edit of the model that leaves it
    equal changes nothing (a condition's, a variant's, or a variant's run of a condition)."""
    values = {k: v[0] for k, v in nominal_values(bound.task).items()}
    model, state = bound.episode(values, scratch=mujoco.MjData(bound.model))
    return simulated_sha256(model, state)


def check_setup_is_a_function(bound: BoundTask) -> None:
    """Refuse an `episode_setup` whose episode depends on more than its arguments (unseeded
    randomness, module state, call order, the clock): the nominal state's episode and the
    low corner's (every parameter at its low value), each set up twice, in the order nominal,
    low, nominal, low, must give the same model and initial state each time. Raises
    `TaskError` (one line naming the task file and the function)."""
    task = bound.task
    if task.episode_setup is None:
        return
    scratch = mujoco.MjData(bound.model)
    nominal = {k: v[0] for k, v in nominal_values(task).items()}
    states = {"nominal": nominal, "low": {p.name: p.low for p in task.state_parameters}}
    seen: dict[str, str] = {}
    for name in (*states, *states):
        sha = simulated_sha256(*bound.episode(states[name], scratch=scratch))
        if seen.setdefault(name, sha) != sha:
            raise NotAFunctionError(
                f"{_where(task)}: episode_setup: not a function of its arguments: the {name} "
                "state's episode differed between two setups (another state's between them); "
                "expected the same model and initial state for the same values (no unseeded "
                "randomness, module state, call order or clock)"
            )


class _ReadValues(dict):
    """A task's `Episodes.values` that notes which parameters its code reads."""

    def __init__(self, values: Mapping[str, np.ndarray]) -> None:
        super().__init__(values)
        self.read: set[str] = set()

    def __getitem__(self, name: str) -> np.ndarray:
        self.read.add(name)
        return super().__getitem__(name)

    def get(self, name: str, default: object = None) -> object:
        self.read.add(name)
        return super().get(name, default)

    def __iter__(self):
        self.read.update(self.keys())
        return super().__iter__()

    def items(self):
        self.read.update(self.keys())
        return super().items()

    def values(self):
        self.read.update(self.keys())
        return super().values()


def read_by_task(task: Task, episodes: Episodes | None) -> set[str]:
    """The state parameters a task reads other than through the physics: an observation the
    policy reads (`Observation.episode_value`), or `success` or `measure` (`Episodes.values`,
    noted as they run on a finished episode's rows). A goal held by no model element is read
    there alone."""
    controller = task.controller
    read = set()
    if isinstance(controller, ClosedLoop):
        by_name = {o.name: o for o in task.observations}
        read |= {by_name[n].parameter for n in controller.observations if n in by_name}
    if episodes is not None:
        noted = _ReadValues(episodes.values)
        seen = replace(episodes, values=noted)
        call(task, "success", task.success, seen)
        call(task, "measure", task.measure, seen)
        read |= noted.read
    return read - {None}


def _check_parameters_applied(bound: BoundTask, episodes: Episodes | None = None) -> None:
    """Each state parameter at its low and at its high value, the others nominal: the episode's
    model, initial state or push must differ, or an observation the policy reads, `success` or
    `measure` must read it (a goal: `read_by_task`, on a nominal episode's `episodes`), or the
    parameter changes nothing."""
    task = bound.task
    read = None
    pushes = getattr(task.controller, "pushes", None)
    scratch = mujoco.MjData(bound.model)
    for p in task.state_parameters:
        seen = []
        for value in (p.low, p.high):
            values = {k: v[0] for k, v in nominal_values(task).items()} | {p.name: value}
            model, state = call(
                task, f"state parameter {p.name!r}", bound.episode, values, scratch=scratch
            )
            push = (
                pushes(bound.model, {k: np.array([v]) for k, v in values.items()})
                if pushes
                else None
            )
            seen.append((simulated_sha256(model, state), repr(push)))
        if seen[0] == seen[1]:
            read = read_by_task(task, episodes) if read is None else read
            if p.name in read:
                continue  # a goal: the policy or the outcome reads it
            raise TaskError(
                f"{_where(task)}: state parameter {p.name!r}: the episode is the same at its low "
                f"and high values and nothing reads it; expected its apply "
                f"({type(p.apply).__name__}) to change the initial state, the model or a push, "
                "or an observation the policy reads, success or a measure to read it (a goal)"
            )


def alike_conditions(
    runs: Mapping[str, tuple[BoundTask, str]],
    conditions: Mapping[str, Mapping[str, float]],
    thresholds: Mapping[str, float],
) -> tuple[str, str] | None:
    """Two of the design's conditions that run alike, or None. Alike at the nominal state
    (`runs`: each one's bound task and nominal episode's hash) is not enough: conditions may
    differ only away from it (a recovery from an offset), so those are run again with each
    state parameter at its low and its high value, and named only if alike there too."""
    seen: dict[str, str] = {}
    for name, (_, digest) in runs.items():
        if digest not in seen:
            seen[digest] = name
            continue
        first = seen[digest]
        probes = [_probe_sha256(runs[n][0], conditions[n], thresholds) for n in (first, name)]
        if probes[0] == probes[1]:
            return first, name
    return None


def episodes_sha256(episodes: Episodes) -> str:
    """The sha256 of a batch's trajectories: states and the controls that made them."""
    digest = hashlib.sha256(np.ascontiguousarray(episodes.physics).tobytes())
    digest.update(np.ascontiguousarray(episodes.ctrl).tobytes())
    return digest.hexdigest()


def _probe_sha256(
    bound: BoundTask, condition: Mapping[str, float], thresholds: Mapping[str, float]
) -> str:
    """The hash of a condition's episodes at each state parameter's low and high value."""
    task = bound.task
    nominal = {p.name: p.nominal_value for p in task.state_parameters}
    probes = [nominal | {p.name: v} for p in task.state_parameters for v in (p.low, p.high)]
    if not probes:
        return ""
    values = {p.name: np.array([s[p.name] for s in probes]) for p in task.state_parameters}
    given = {t.name: float(thresholds.get(t.name, t.default)) for t in task.thresholds}
    printer = mujoco.get_mju_user_warning()
    mujoco.set_mju_user_warning(lambda _: None)
    try:
        return "".join(
            episodes_sha256(b.episodes)
            for b in iter_batches(bound, values, condition, thresholds=given, nthread=0)
        )
    finally:
        mujoco.set_mju_user_warning(printer)
