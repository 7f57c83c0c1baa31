"""A task's episodes, in batches: models and initial states from the states' values, the physics
by `mujoco.rollout` (open loop) or the lockstep closed-loop engine, then success, the task's
measures and one failure category per failed episode.

Every episode starts from its own full state with a zero warm start, so its physics never
depends on the batch it ran in or the number of threads. An open-loop task's controls are
computed once per condition, before any batch, so they cannot depend on it either; a
closed-loop policy could, and every batch checks it (`closed_loop.check_replayed`). The task's
measure, success and pushes read a whole batch too: verify re-simulates its sample each
episode alone, so one that depends on the batch is not confirmed.
"""

from __future__ import annotations

import copy
from collections.abc import Iterator, Mapping
from dataclasses import dataclass

import mujoco
import numpy as np
from mujoco import rollout

from mjtrial.sim import closed_loop, phases
from mjtrial.sim.low_level import ControllerError, MakeController
from mjtrial.sim.physics import FULLPHYSICS, halted, nonfinite, steps_simulated
from mjtrial.task import (
    NONFINITE_ACTION,
    UNHEALTHY,
    BoundTask,
    ClosedLoop,
    Episodes,
    OpenLoop,
    TaskError,
    call,
    expect_rows,
)

# Episodes per batch in the pipeline, sized by memory: a batch's trajectories, held twice (the
# engine's output and the recording writer's copy), fill at most BATCH_BYTES. Long episodes
# (about 1 MB each: a 2,100-step episode of a 24-number state) then run about 25 at a time, as a
# rollout job's working memory allows; short ones (0.2 MB) about 130, which a closed-loop policy
# needs: every control instant costs a policy call and a `rollout` call whose threads cost about
# 130 µs to start, so 16 episodes of 5 steps ran slower on 2 threads than on 1
# (benchmarks/bench_policy_file.py). Beyond MAX_BATCH episodes nothing got faster.
BATCH_BYTES = 24 * 2**20
MAX_BATCH = 256
# A low-level controller's numpy calls are paid once per batch at every physics step: robosuite's
# operational-space controller cost about 3 times less per episode in batches of 128 than of 19
# (what BATCH_BYTES gives a 1,125-step episode of robosuite's Panda), so such batches hold at
# least this many. Each episode holds its own MjData throughout (about 1.7 MB for the Panda's
# scene, its contacts' arena touched): a rollout job on that scene peaked at 421 MB with
# 64, within the 400 MB bar with 32, and its CPU per episode did not tell 32 from 64
# (`benchmarks/bench_memory.py`, `benchmarks/bench_low_level.py --batch`).
LOW_LEVEL_BATCH = 32
UNCLASSIFIED = "unclassified"  # a failure that none of the task's categories describes


@dataclass(frozen=True)
class Batch:
    """A batch of finished episodes: their state values, trajectories and outcome columns."""

    values: dict[str, np.ndarray]  # state column -> (n,)
    episodes: Episodes
    outcome: dict[str, np.ndarray]  # success, failure_category and the task's measures


def warning_names(counters: np.ndarray) -> str:
    """MuJoCo warnings that fired, by name (e.g. "mjWARN_BADQACC"), comma-separated."""
    return ",".join(mujoco.mjtWarning(i).name for i, n in enumerate(counters) if n)


def open_loop_warnings(model: mujoco.MjModel, initial: np.ndarray, ctrl: np.ndarray) -> str:
    """The warnings that stop an open-loop episode, from a plain `mj_step` run of it that ends
    at the first one (as `mujoco.rollout` does): rollout reports only the frozen state."""
    data = mujoco.MjData(model)
    mujoco.mj_setState(model, data, initial, FULLPHYSICS)
    for row in ctrl:
        if any(w.number for w in data.warning):
            break
        data.ctrl[:] = row
        mujoco.mj_step(model, data)
    return warning_names(np.array([w.number for w in data.warning]))


def classify(
    bound: BoundTask,
    success: np.ndarray,
    healthy_rows: np.ndarray,
    measures,
    thresholds,
    failed_action: np.ndarray | None = None,
):
    """Each failed episode's category (None for a success): unhealthy first, then
    `NONFINITE_ACTION` where the policy's action went non-finite (`failed_action`), then the
    task's categories in order, the first that applies; `UNCLASSIFIED` when none does."""
    category = np.full(success.shape, None, dtype=object)
    task = bound.task
    tests = [
        (
            c.name,
            np.asarray(call(task, f"failure category {c.name!r}", c.test, measures, thresholds)),
        )
        for c in task.failure_categories
    ]
    for i in np.flatnonzero(~success):
        if not healthy_rows[i]:
            category[i] = UNHEALTHY
            continue
        if failed_action is not None and failed_action[i]:
            category[i] = NONFINITE_ACTION
            continue
        category[i] = next((name for name, hit in tests if hit[i]), UNCLASSIFIED)
    return category


def episode_bytes(model: mujoco.MjModel, steps: int) -> float:
    """An episode's trajectory, sensor values and controls, held twice (see BATCH_BYTES)."""
    per_step = mujoco.mj_stateSize(model, FULLPHYSICS) + model.nsensordata + model.nu
    return 2.0 * steps * per_step * 8


def batch_size_for(model: mujoco.MjModel, steps: int) -> int:
    """Episodes per batch: as many as BATCH_BYTES holds, at least 1, at most MAX_BATCH."""
    return int(max(1, min(MAX_BATCH, BATCH_BYTES // episode_bytes(model, steps))))


def episode_steps(bound: BoundTask, condition: Mapping[str, float]) -> int:
    """Physics steps of an episode under a condition."""
    task, model = bound.task, bound.model
    params = task.parameters(condition)
    controller = task.controller
    if isinstance(controller, OpenLoop):
        if controller.n_steps is not None:
            return int(call(task, "n_steps", controller.n_steps, model, params))
        return len(call(task, "controls", controller.controls, model, params))
    return call(task, "timing", controller.timing, model, params).n_steps


def low_level_of(bound: BoundTask, params: Mapping[str, float]) -> MakeController | None:
    """What builds the task's low-level controller for a condition (`ClosedLoop.low_level`, its
    errors naming the task file), or None when the policy drives the actuators itself."""
    controller = bound.task.controller
    make = getattr(controller, "low_level", None)
    if make is None:
        return None
    return lambda: call(bound.task, "low_level", make, bound.model, params)


# A batch's episodes with model parameters each run on a copy of the model (one per batch slot,
# reused batch after batch where the task's parameters allow: `BoundTask.reuses_models`),
# textures included: dm_control's reacher is 11.8 MB with its skybox, so it gets 8 slots.
# Outcomes never depend on the batch, so this changes memory and speed, not results.
MODEL_COPIES_BYTES = 96 * 2**20


def iter_batches(
    bound: BoundTask,
    values: Mapping[str, np.ndarray],
    condition: Mapping[str, float],
    *,
    thresholds: Mapping[str, float],
    nthread: int = 0,
    batch_size: int | None = None,
    replay_check: bool = True,
) -> Iterator[Batch]:
    """Run the episodes whose state values are the columns `values`, `batch_size` at a time.

    Args:
      bound: the task, its model loaded.
      values: state column -> (n,) values (the states table without `state_id`, or with it).
      condition: the condition's protocol parameters (defaults are filled in).
      thresholds: the failure categories' thresholds by name.
      nthread: rollout threads (0: the calling thread).
      batch_size: episodes per batch (memory is bounded by it); by default `batch_size_for`.
      replay_check: replay a closed-loop batch each row alone (`closed_loop.check_replayed`).
        Off only where the episodes are not results but a search's scores (training a policy,
        tuning a controller): it cost 2.6 times the episodes' own time there, and what the
        search chooses is checked when its evaluation runs.
    """
    task, model = bound.task, bound.model
    if batch_size is None:
        batch_size = batch_size_for(model, episode_steps(bound, condition))
        if getattr(task.controller, "low_level", None) is not None:
            batch_size = max(batch_size, LOW_LEVEL_BATCH)
    copies = bound.setup_copies or any(p.apply.stage == "model" for p in task.state_parameters)
    if copies:  # each batch slot holds a copy of the model, textures and all
        batch_size = max(1, min(batch_size, MODEL_COPIES_BYTES // mujoco.mj_sizeModel(model)))
    params = task.parameters(condition)
    n = len(next(iter(values.values())))
    scratch = mujoco.MjData(model)
    controller = task.controller
    if isinstance(controller, OpenLoop):
        ctrl = np.asarray(
            call(task, "controls", controller.controls, model, params), dtype=np.float64
        )
    else:
        assert isinstance(controller, ClosedLoop)
        timing = call(task, "timing", controller.timing, model, params)
        policy = call(task, "policy", controller.policy, model, params)
        low_level = low_level_of(bound, params)
    episode_values = [p.name for p in task.state_parameters]
    datas = [mujoco.MjData(model) for _ in range(max(1, nthread))]
    # one copy of the model per batch slot, reused batch after batch where it can be
    slots = (
        [copy.copy(model) for _ in range(min(batch_size, n))]
        if copies and bound.reuses_models
        else []
    )
    with rollout.Rollout(nthread=nthread) as runner:
        for start in range(0, n, batch_size):
            rows = {k: np.asarray(v[start : start + batch_size]) for k, v in values.items()}
            size = len(next(iter(rows.values())))
            with phases.phase("episode setup"):
                models, initial = [], []
                for i in range(size):
                    m, s = bound.episode(
                        {k: float(v[i]) for k, v in rows.items()},
                        scratch=scratch,
                        model=slots[i] if slots else None,
                    )
                    models.append(m)
                    initial.append(s)
                initial_states = np.stack(initial)
            mocap = None  # (size, n_steps, nmocap, 7) when an action moves a mocap body
            if isinstance(controller, OpenLoop):
                with phases.phase("physics", every_thread=True):
                    physics, sensordata = runner.rollout(models, datas, initial_states, ctrl[None])
                failed_action = None
                applied = np.broadcast_to(ctrl, (size, *ctrl.shape))
            else:
                pushes = (
                    call(task, "pushes", controller.pushes, model, rows)
                    if controller.pushes
                    else None
                )
                observe = bound.observer(
                    controller.observations,
                    {p: rows[p] for p in episode_values},
                    params=params,
                    n_controls=timing.n_controls,
                    models=models,
                )
                try:
                    with phases.phase("physics + policy", every_thread=True):
                        result = closed_loop.run_batch(
                            models,
                            initial_states,
                            policy,
                            observe,
                            timing,
                            runner=runner,
                            datas=datas,
                            pushes=pushes,
                            actuation=bound.actuation,
                            check=replay_check,
                            low_level=low_level,
                            carry_warmstart=controller.carry_warmstart,
                        )
                except (closed_loop.PolicyError, ControllerError) as err:
                    where = controller.source or task.source or task.name
                    raise TaskError(f"{where}: {err}") from None
                physics, sensordata = result.physics, result.sensordata
                failed_action = result.failed_action
                applied = result.applied_controls(timing.steps_per_control)
                if result.mocap is not None:
                    mocap = np.repeat(result.mocap, timing.steps_per_control, axis=1)
            with phases.phase("measures + outcome"):
                stopped, broken = halted(physics), nonfinite(physics)
                ok = ~stopped & ~broken
                episodes = Episodes(
                    model,
                    params,
                    physics,
                    sensordata,
                    ok,
                    applied,
                    {p: rows[p] for p in episode_values},
                    mocap,
                )
                measures = dict(call(task, "measure", task.measure, episodes))
                missing = [m.name for m in task.own_measures if m.name not in measures]
                if missing:
                    raise TaskError(
                        f"{task.source or task.name}: measure: expected a value for {missing[0]!r}"
                    )
                for m in task.own_measures:
                    expect_rows(task, f"measure[{m.name!r}]", measures[m.name], size)
                success = call(task, "success", task.success, episodes)
                expect_rows(task, "success", success, size, dtype=bool)
                success = np.asarray(success, dtype=bool) & ok
                if failed_action is not None:
                    success &= ~failed_action
                warning = np.full(size, "", dtype=object)
                for i in np.flatnonzero(~ok):
                    if isinstance(controller, OpenLoop):
                        warning[i] = open_loop_warnings(models[i], initial_states[i], ctrl)
                    else:
                        warning[i] = warning_names(
                            closed_loop.reference_episode(
                                models[i],
                                initial_states[i],
                                policy,
                                bound.observer(
                                    controller.observations,
                                    {p: rows[p][i : i + 1] for p in episode_values},
                                    params=params,
                                    n_controls=timing.n_controls,
                                    models=models[i : i + 1],
                                ),
                                timing,
                                pushes=pushes.rows(slice(i, i + 1)) if pushes else None,
                                actuation=bound.actuation,
                                low_level=low_level,
                                carry_warmstart=controller.carry_warmstart,
                            ).warnings
                        )
                outcome = {
                    "success": success,
                    # copies: a view would keep the batch's trajectories alive with the columns
                    **{
                        m.name: np.array(measures[m.name], dtype=np.float64)
                        for m in task.own_measures
                    },
                    "steps_simulated": steps_simulated(physics),
                    "nonfinite": broken,
                    "warning": warning,
                    "failure_category": classify(
                        bound, success, ok, measures, thresholds, failed_action
                    ),
                }
            yield Batch(rows, episodes, outcome)
