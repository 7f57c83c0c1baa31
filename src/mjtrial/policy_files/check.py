"""`mjtrial policy check FILE --task T`: a policy file against a task before any experiment
names it: the contract against the task and the graph, a nominal episode, batch invariance (as
many states as the engine runs in one batch for this task, each episode alone against all in
the engine's batches, bit for bit) and the time per call."""

from __future__ import annotations

import math
import time
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path

import jsonschema
import numpy as np

from mjtrial.policy_files.file import PolicyFile, RelativeColumn, load_policy_file, policy_task
from mjtrial.sim.engine import batch_size_for, episode_steps, iter_batches
from mjtrial.task import BoundTask, Task, TaskError, load_task
from mjtrial.task.checks import nominal_values

TIMED_CALLS = 200  # calls per timed batch size (the median is reported)


@dataclass(frozen=True)
class PolicyCheck:
    """What `check_policy_file` found.

    Attributes:
      policy: the policy file, checked against the task and the graph.
      privileged: the privileged observations it reads (a config must allow each).
      nominal: the nominal episode's outcome: "success" or its failure category.
      invariant: every episode the same bits alone as in the engine's batches.
      call_seconds: batch size -> median seconds per call (1 row, and the engine's batch).
      batches: the sizes of the engine's batches the episodes ran in together: one batch of
        the engine's size for the task (`engine.batch_size_for`, what a rollout's batch is at
        most) unless the task's memory budget splits them.
    """

    policy: PolicyFile
    privileged: tuple[str, ...]
    nominal: str
    invariant: bool
    call_seconds: Mapping[int, float]
    batches: tuple[int, ...]

    def lines(self) -> list[str]:
        """The check's report, one fact a line."""
        c = self.policy.contract
        times = ", ".join(f"{n} row(s) {s * 1e6:.0f} µs" for n, s in self.call_seconds.items())
        settings = self.policy.settings
        return [
            f"{self.policy.path}: contract {c.source}, sha256 {self.policy.sha256}",
            f"  task {c.task}: observations {', '.join(c.observations)}; actuators "
            f"{', '.join(_actuator(a, c.signs_of(k)) for k, a in enumerate(c.actuators))} "
            f"({c.action_scale})"
            + "".join(f", mocap body {m['body']}" for m in c.mocap)
            + f"; control period {c.control_period:g} s",
            "  privileged observations: "
            + (
                f"{', '.join(self.privileged)} (a config must allow each, with a reason)"
                if self.privileged
                else "none"
            ),
            f"  nominal episode: {self.nominal}",
            f"  batch invariance: {sum(self.batches)} episodes alone and in "
            + (
                "one batch (the engine's) "
                if len(self.batches) == 1
                else f"the engine's {len(self.batches)} batches ({_sizes(self.batches)}) "
            )
            + ("agree bit for bit" if self.invariant else "DIFFER: results would depend on batch"),
            f"  per call (median of {TIMED_CALLS}): {times}",
            f"  onnxruntime {settings['onnxruntime']}, {settings['intra_op_num_threads']} thread, "
            f"{settings['execution_mode']}, {settings['graph_optimization_level']}",
        ]


def _actuator(entry: str | tuple[str, ...] | RelativeColumn, signs: tuple[int, ...] = ()) -> str:
    """A contract's actuator entry as said: one name, or the names one column drives (each
    with its sign when the column has signs: `[+left, -right]`; relative to their joints:
    `relative [a, b] x 0.5`)."""
    if isinstance(entry, RelativeColumn):
        return f"relative {_actuator(entry.actuators)} x {entry.scale:g}"
    if isinstance(entry, str):
        return entry
    if signs:
        entry = tuple(f"{'+' if s > 0 else '-'}{n}" for n, s in zip(entry, signs, strict=True))
    return f"[{', '.join(entry)}]"


def _sizes(batches: tuple[int, ...]) -> str:
    """Batch sizes as said: `5, 3`, or `26 of 5, 1 of 1` when some repeat."""
    counts = {n: batches.count(n) for n in batches}
    if all(c == 1 for c in counts.values()):
        return ", ".join(map(str, batches))
    return ", ".join(f"{c} of {n}" for n, c in counts.items())


def _outcomes(bound: BoundTask, values, condition, thresholds, *, batch_size: int):
    batches = iter_batches(bound, values, condition, thresholds=thresholds, batch_size=batch_size)
    return [(b.episodes.physics, b.outcome["failure_category"]) for b in batches]


def check_policy_file(
    path: str | Path, task: Task, *, condition: Mapping[str, float] | None = None
) -> PolicyCheck:
    """Check a policy file against a task (see the module's docstring) under `condition` (the
    task's defaults if None). Raises `PolicyFileError` or `TaskError` (one line) where the
    contract, the graph or the task's code refuse it."""
    policy = load_policy_file(path, task)
    bound = BoundTask.of(policy_task(task, policy))
    condition = dict(condition or {})
    thresholds = {t.name: t.default for t in task.thresholds}
    declared = {o.name: o for o in task.observations}
    privileged = tuple(n for n in policy.observations if declared[n].source is None)
    ((_, category),) = _outcomes(bound, nominal_values(task), condition, thresholds, batch_size=1)
    # as many states as a rollout's batch holds at most: a graph that depends on the batch
    # only in large batches shows it here, not first in the rollout (`closed_loop`'s replays)
    batch = batch_size_for(bound.model, episode_steps(bound, condition))
    rng = np.random.default_rng(0)
    values = {p.name: rng.uniform(p.low, p.high, batch) for p in task.state_parameters}
    # the engine may split the episodes (a task's memory budget): every batch is compared
    together = _outcomes(bound, values, condition, thresholds, batch_size=batch)
    alone = _outcomes(bound, values, condition, thresholds, batch_size=1)
    invariant = np.array_equal(
        np.concatenate([physics for physics, _ in together]),
        np.concatenate([physics for physics, _ in alone]),
        equal_nan=True,
    )
    batch_policy = policy.policy(bound.model, task.parameters(condition))
    width = sum(bound.widths(policy.observations))
    call_seconds = {}
    # a reference episode's batch, and the engine's for this task
    for n in sorted({1, batch}):
        rows = rng.normal(size=(n, width))
        batch_policy.reset(n)
        spent = []
        for _ in range(TIMED_CALLS):
            start = time.perf_counter()
            batch_policy(rows)
            spent.append(time.perf_counter() - start)
        call_seconds[n] = float(np.median(spent))
    return PolicyCheck(
        policy=policy,
        privileged=privileged,
        nominal="success" if category[0] is None else f"failed ({category[0]})",
        invariant=invariant,
        call_seconds=call_seconds,
        batches=tuple(len(physics) for physics, _ in together),
    )


def parse_settings(items: Sequence[str]) -> dict[str, float]:
    """`--set NAME=VALUE` items as a condition; `ValueError` (one line) for an item that is not
    NAME=a finite number."""
    condition = {}
    for item in items:
        name, _, value = item.partition("=")
        try:
            condition[name] = float(value)
        except ValueError:
            condition[name] = math.nan
        if not math.isfinite(condition[name]):
            raise ValueError(f"--set {item}: expected NAME=NUMBER, a finite number")
    return condition


def policy_check_task(
    reference: str, condition: Mapping[str, float], *, repo_root: Path = Path(".")
) -> Task:
    """The task `--task` names: a task.py path, an installed task's name, or the name of one of
    the repository's own tasks (`tasks/<name>/task.py`, as a contract names it); `TaskError`
    (one line) for a condition's value that is not one of its protocol parameters within the
    bounds the config's schema holds a condition to."""
    own = Path(repo_root) / "tasks" / reference / "task.py"
    named = own.as_posix() if not reference.endswith(".py") and own.is_file() else reference
    task = load_task(named, repo_root=Path(repo_root))
    known = {p.name: p for p in task.protocol_parameters}
    for name, value in condition.items():
        if name not in known:
            raise TaskError(f"{reference}: --set {name}: not a protocol parameter")
        error = jsonschema.exceptions.best_match(
            jsonschema.Draft202012Validator(known[name].schema()).iter_errors(value)
        )
        if error is not None:
            raise TaskError(
                f"{reference}: --set {name}={value:g}: expected within the task's bounds "
                f"({error.message})"
            )
    return task
