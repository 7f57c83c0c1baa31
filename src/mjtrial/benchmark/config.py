"""Check a benchmark's config (`config/benchmark.yaml`): the schema, then what it cannot say.

A benchmark names tasks by their experiment configs (the task, its model, the evaluation and
development states, the failure thresholds), and methods by what each fixes and tunes on each
task. Every problem is one line naming the file, the key and what was expected, before any
work: a task's own config is checked as an experiment's is, and named when it fails.
"""

from __future__ import annotations

import dataclasses
import glob
import re
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import jsonschema

from mjtrial import REPO_ROOT
from mjtrial.benchmark import is_benchmark  # noqa: F401 - read from here too
from mjtrial.benchmark.stats import SEEDS_FOR_DEVELOPMENT_DECISION, SEEDS_FOR_REPORTED_RESULT
from mjtrial.benchmark.tuning import check_search, minimum_budget
from mjtrial.config import (
    ConfigError,
    _non_finite,
    _schema_message,
    _Validator,
    check_config,
    policy_path_problem,
    read_config_file,
)
from mjtrial.crate.description import crate_description
from mjtrial.files.layout import shard_ids, shard_range
from mjtrial.files.schemas import packaged_schema
from mjtrial.policy_files.file import load_policy_file, policy_task
from mjtrial.task import Task, TaskError, load_task

SCHEMA_PATH = REPO_ROOT / "workflow" / "schemas" / "benchmark.schema.yaml"


@dataclass(frozen=True)
class BenchmarkTask:
    """One task of a benchmark: its experiment config, read and checked, and the task."""

    name: str
    config_path: str  # the experiment config, as the benchmark names it
    config: dict[str, Any]
    task: Task
    condition: dict[str, float]  # what every method runs with, under its own values
    # method -> training seed -> its policy file, for a method that runs policy files here
    policies: Mapping[str, Mapping[int, str]] = dataclasses.field(default_factory=dict)


NOT_RUN = "none"  # a method's entry for a task it does not apply to


def method_tasks(config: Mapping[str, Any], method: str) -> list[str]:
    """The tasks a method runs on: every task its entry does not mark `none`."""
    given = config["benchmark"]["methods"][method]["tasks"]
    return [t for t in config["benchmark"]["tasks"] if given.get(t) != NOT_RUN]


def benchmark_runs(config: Mapping[str, Any]) -> list[tuple[str, str, int]]:
    """Every (task, method, training seed) the benchmark trains and evaluates, in task,
    method, seed order: a method marked `none` on a task has no run there."""
    bench = config["benchmark"]
    return [
        (t, m, s)
        for t in bench["tasks"]
        for m in bench["methods"]
        if t in method_tasks(config, m)
        for s in bench["seeds"]
    ]


def checkpoint_files(pattern: str, seeds: list[int], *, repo_root: Path) -> dict[int, str]:
    """The policy file of each training seed: the files `pattern` matches (relative to
    `repo_root`), each holding its seed as the only number of its name (`seed-3.onnx`: seed 3;
    `seed-3-v2.onnx` is refused). `ValueError` (the expectation, one line) unless exactly one
    file per seed matches."""
    if Path(pattern).is_absolute() or ".." in Path(pattern).parts:
        raise ValueError("expected a glob inside the repository, relative to it")
    found = sorted(glob.glob(pattern, root_dir=repo_root))
    by_seed: dict[int, list[str]] = {}
    for name in found:
        numbers = re.findall(r"\d+", Path(name).stem)
        if len(numbers) > 1:
            raise ValueError(
                f"{name} has {len(numbers)} numbers in its name ({', '.join(numbers)}); expected "
                "its training seed as the only number (seed-3.onnx: seed 3)"
            )
        by_seed.setdefault(int(numbers[-1]) if numbers else -1, []).append(name)
    if sorted(by_seed) != sorted(seeds) or any(len(v) > 1 for v in by_seed.values()):
        got = ", ".join(found) if found else "no file"
        raise ValueError(
            f"expected one file per training seed {sorted(seeds)}, each with its seed as the "
            f"only number of its name, got {len(found)}: {got}"
        )
    return {s: Path(by_seed[s][0]).as_posix() for s in seeds}


def check_benchmark_config(
    config: Mapping[str, Any], *, source: str, repo_root: Path = REPO_ROOT
) -> dict[str, BenchmarkTask]:
    """The benchmark's tasks, or `ConfigError` (one line: file, key, expectation)."""

    def fail(key: str, expectation: str):
        raise ConfigError(f"{source}: {key}: {expectation}")

    bad = _non_finite(dict(config))
    if bad:
        fail(bad[0], f"expected a finite number, got {bad[1]}")
    schema = packaged_schema(SCHEMA_PATH)
    error = jsonschema.exceptions.best_match(_Validator(schema).iter_errors(dict(config)))
    if error is not None:
        key, _, expectation = _schema_message(error).partition(": ")
        fail(key, expectation)
    bench = config["benchmark"]

    seeds = bench["seeds"]
    # Fewer seeds support no result at all (`stats.seed_count_label`): refused here, not by
    # the summary after every training and evaluation ran.
    if len(seeds) < SEEDS_FOR_DEVELOPMENT_DECISION:
        fail(
            "benchmark.seeds",
            f"expected at least {SEEDS_FOR_DEVELOPMENT_DECISION} training seeds for a "
            f"{bench['result']} result ({SEEDS_FOR_REPORTED_RESULT} or more to report it as more "
            f"than a development decision), got {len(seeds)}",
        )

    tasks = {
        name: _benchmark_task(name, entry, repo_root=Path(repo_root), fail=fail)
        for name, entry in bench["tasks"].items()
    }
    for name, method in bench["methods"].items():
        policies = _check_method(name, method, tasks, seeds, repo_root=Path(repo_root), fail=fail)
        for task, files in policies.items():
            tasks[task] = dataclasses.replace(
                tasks[task], policies={**tasks[task].policies, name: files}
            )
    budgets = {name: m["budget"] for name, m in bench["methods"].items()}
    if len(set(budgets.values())) > 1 and "unequal_budgets" not in bench:
        fail(
            "benchmark.unequal_budgets",
            f"missing; the methods' budgets differ ({budgets}): expected the reason, which the "
            "report prints beside them",
        )
    return tasks


def _benchmark_task(name: str, entry: Mapping[str, Any], *, repo_root: Path, fail) -> BenchmarkTask:
    key = f"benchmark.tasks.{name}"
    path = repo_root / entry["experiment"]
    if not path.is_file():
        fail(
            f"{key}.experiment", f"expected an experiment config file, got {entry['experiment']!r}"
        )
    try:
        experiment = read_config_file(path)
        check_config(experiment, source=entry["experiment"], repo_root=repo_root)
    except ConfigError as err:
        fail(f"{key}.experiment", f"its config is not runnable: {err}")
    try:
        task = load_task(experiment["task"], repo_root=repo_root)
    except TaskError as err:  # checked above; a task that fails the second time is named too
        fail(f"{key}.experiment", str(err))
    condition = {k: float(v) for k, v in entry.get("condition", {}).items()}
    for field in ("condition", "reference"):
        try:
            check_search(task, {}, entry.get(field, {}), require_tuned=False)
        except ValueError as err:
            fail(*_search_problem(err, f"{key}.{field}."))
    return BenchmarkTask(name, entry["experiment"], experiment, task, condition)


def _check_method(
    name: str,
    method: Mapping[str, Any],
    tasks: Mapping[str, BenchmarkTask],
    seeds: list[int],
    *,
    repo_root: Path,
    fail,
) -> dict[str, dict[int, str]]:
    """Check one method; its policy files per task and training seed (none: {})."""
    key = f"benchmark.methods.{name}"
    given = method["tasks"]
    missing = [t for t in tasks if t not in given]
    if missing:
        fail(
            f"{key}.tasks.{missing[0]}",
            f"missing; expected what the method does on every task ({NOT_RUN!r} where it "
            "does not apply)",
        )
    unknown = [t for t in given if t not in tasks]
    if unknown:
        fail(
            f"{key}.tasks.{unknown[0]}",
            f"not a task of the benchmark; expected one of {list(tasks)}",
        )
    if all(spec == NOT_RUN for spec in given.values()):
        fail(
            f"{key}.tasks", f"expected at least one task the method runs on, got {NOT_RUN!r} on all"
        )
    tunes, policies = False, {}
    for task_name, spec in given.items():
        if spec == NOT_RUN:
            continue
        bt = tasks[task_name]
        if "policy" in spec:
            policies[task_name] = _policy_files(
                spec, bt, seeds, key=f"{key}.tasks.{task_name}", repo_root=repo_root, fail=fail
            )
        fixed = {**bt.condition, **spec.get("fixed", {})}
        tune = spec.get("tune", {})
        fixed = {k: v for k, v in fixed.items() if k not in tune}
        try:
            check_search(bt.task, tune, fixed, require_tuned=False)
        except ValueError as err:
            fail(*_search_problem(err, f"{key}.tasks.{task_name}."))
        tunes = tunes or bool(tune)
        if tune and method["budget"] > 0 and "episodes_per_candidate" in method:
            n_dev = bt.config["states"]["n"]  # the development states: as many as evaluated
            least = minimum_budget(
                len(tune),
                episodes_per_candidate=method["episodes_per_candidate"],
                n_development=n_dev,
            )
            if method["budget"] < least:
                fail(
                    f"{key}.budget",
                    f"expected at least {least} episodes to tune on {task_name} (one generation "
                    f"of candidates, and the finalists on its {n_dev} development states), got "
                    f"{method['budget']}",
                )
    if tunes and method["budget"] == 0:
        fail(f"{key}.budget", "expected a budget of episodes > 0 for a method that tunes")
    if not tunes and method["budget"] != 0:
        fail(f"{key}.budget", f"expected 0 for a method that tunes nothing, got {method['budget']}")
    if tunes and "episodes_per_candidate" not in method:
        fail(f"{key}.episodes_per_candidate", "missing; a method that tunes needs it")
    return policies


def _policy_files(
    spec: Mapping[str, Any],
    bt: BenchmarkTask,
    seeds: list[int],
    *,
    key: str,
    repo_root: Path,
    fail,
) -> dict[int, str]:
    """A method's policy files on one task, one per training seed, each checked against the
    task and its graph (`load_policy_file`) before any work."""
    if "tune" in spec:
        fail(f"{key}.tune", "a method that runs policy files tunes nothing; expected no tune")
    try:
        files = checkpoint_files(spec["policy"], seeds, repo_root=repo_root)
    except ValueError as err:
        fail(f"{key}.policy", f"{spec['policy']!r}: {err}")
    for path in files.values():
        if problem := policy_path_problem(path, repo_root=repo_root):
            fail(f"{key}.policy", problem)
        try:
            policy_task(bt.task, load_policy_file(repo_root / path, bt.task))
        except TaskError as err:  # a PolicyFileError, or observations the task cannot give
            fail(f"{key}.policy", str(err).replace(f"{repo_root}/", ""))
    return files


def _search_problem(err: ValueError, prefix: str) -> tuple[str, str]:
    """A `check_search` problem (`tuned.NAME: ...`, `fixed.NAME: ...`) as the config's key
    under `prefix` (`...tune.NAME`, `...fixed.NAME`; a condition's key has no `fixed.`) and
    the expectation."""
    where, _, expectation = str(err).partition(": ")
    kind, _, name = where.partition(".")
    field = {"tuned": "tune.", "fixed": "fixed."}.get(kind, "")
    if prefix.endswith(("condition.", "reference.")):
        field = ""
    return f"{prefix}{field}{name or kind}", expectation


def train_slice(
    config: Mapping[str, Any], tasks: Mapping[str, BenchmarkTask], task: str, method: str, seed: int
) -> dict[str, Any]:
    """What one training job depends on (its rule's params, its stamp's record): the task's
    reference, thresholds and development seed, the benchmark's condition for it, the method's
    budget and what it fixes and tunes on this task, the seed. Nothing else reruns it."""
    spec = config["benchmark"]["methods"][method]
    experiment = tasks[task].config
    given = {k: v for k, v in spec["tasks"][task].items() if v}
    if "policy" in given:  # the seed's own file: the other seeds' files do not rerun it
        given["policy"] = tasks[task].policies[method][seed]
    return {
        "task": experiment["task"],
        "failure_taxonomy": dict(experiment.get("failure_taxonomy", {})),
        "development_seed": experiment["states"]["development_seed"],
        "condition": dict(tasks[task].condition),
        "method": {
            "name": method,
            "budget": spec["budget"],
            **(
                {"episodes_per_candidate": spec["episodes_per_candidate"]}
                if "episodes_per_candidate" in spec
                else {}
            ),
            **given,
        },
        "seed": seed,
    }


def evaluation_shards(tasks: Mapping[str, BenchmarkTask], task: str) -> list[str]:
    """The shards of a task's evaluation states: its experiment's `rollout.shard_size`."""
    experiment = tasks[task].config
    return shard_ids(experiment["states"]["n"], experiment["rollout"]["shard_size"])


def evaluation_shard_range(
    tasks: Mapping[str, BenchmarkTask], task: str, shard: str
) -> tuple[int, int]:
    """The state ids [first, stop) of one shard of a task's evaluation states."""
    experiment = tasks[task].config
    return shard_range(shard, experiment["rollout"]["shard_size"], experiment["states"]["n"])


def evaluate_slice(tasks: Mapping[str, BenchmarkTask], task: str) -> dict[str, Any]:
    """What an evaluation job depends on besides its parameter file: the task and thresholds."""
    experiment = tasks[task].config
    return {
        "task": experiment["task"],
        "failure_taxonomy": dict(experiment.get("failure_taxonomy", {})),
    }


def crate_slice(config: Mapping[str, Any], *, command: str, config_file: str) -> dict[str, Any]:
    """What a benchmark's crate says of the run beyond its files (an experiment's crate reads
    it from the manifest): the question, the config file and the command that rebuilds it;
    the license, authors and keywords as an experiment's (`crate_description`)."""
    return {
        **crate_description(config),
        "design": {"question": config["benchmark"]["question"]},
        "rerun": {"command": command, "config_file": config_file},
    }


def summary_slice(config: Mapping[str, Any]) -> dict[str, Any]:
    """What the summary depends on: the tasks, methods (budgets, descriptions, the tasks of
    one that does not run on every task), seeds, the
    headline, the reason for unequal budgets and the analysis settings."""
    bench = config["benchmark"]
    return {
        "question": bench["question"],
        "tasks": list(bench["tasks"]),
        "methods": {
            m: {
                "description": spec["description"],
                "budget": spec["budget"],
                # a method that does not run on every task: the tasks it runs on
                **({"tasks": method_tasks(config, m)} if _skips_a_task(config, m) else {}),
            }
            for m, spec in bench["methods"].items()
        },
        "seeds": list(bench["seeds"]),
        "headline": bench["headline"],
        "unequal_budgets": bench.get("unequal_budgets"),
        "analysis": dict(bench["analysis"]),
    }


def _skips_a_task(config: Mapping[str, Any], method: str) -> bool:
    return method_tasks(config, method) != list(config["benchmark"]["tasks"])


# Episodes of each kind (closest successes, highest scores) per task in replay/closest_calls.rrd
CLOSEST_CALLS_DEFAULT = 10

# The solvability check when the config says nothing (`benchmark.solvability`).
SOLVABILITY_DEFAULTS = {"max_corner_parameters": 6, "states": 64, "seed": 0}


def solvability_slice(
    config: Mapping[str, Any], tasks: Mapping[str, BenchmarkTask], task: str
) -> dict[str, Any]:
    """What a task's solvability check depends on: its ranges, its reference controller (the
    benchmark's condition with the task's `reference` on top) and the probe's settings."""
    experiment = tasks[task].config
    entry = config["benchmark"]["tasks"][task]
    return {
        "task": experiment["task"],
        "ranges": dict(experiment["states"]["ranges"]),
        "reference": {**tasks[task].condition, **entry.get("reference", {})},
        "failure_taxonomy": dict(experiment.get("failure_taxonomy", {})),
        **SOLVABILITY_DEFAULTS,
        **config["benchmark"].get("solvability", {}),
    }


def closest_calls_slice(
    config: Mapping[str, Any], tasks: Mapping[str, BenchmarkTask]
) -> dict[str, Any]:
    """What the closest calls depend on besides the evaluations: how many of each kind, and
    each task's evaluation settings and logging rate (its experiment's `recording.rate_hz`)."""
    return {
        "k": config["benchmark"].get("closest_calls", CLOSEST_CALLS_DEFAULT),
        "tasks": {
            task: {
                "evaluate_slice": evaluate_slice(tasks, task),
                "rate_hz": tasks[task].config["recording"]["rate_hz"],
            }
            for task in tasks
        },
    }
