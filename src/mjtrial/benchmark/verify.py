"""Verify a benchmark's results: the split between development and evaluation states held, and
every file is the one the next job read.

Checked from the files alone (any machine the folder is copied to): each task's development
and evaluation states were drawn as such (their stamps' rules) and share no state; each
training's stamp names the task's development states, with their sha256 of now; each
evaluation's stamp names the task's evaluation states and the parameter file, with their
sha256 of now; the stamps of the summary and of the closest calls (table and replay file) name
every evaluation and parameter file as they are; the report's names the summary and the
closest calls' table. A training that read anything but its development states fails.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow.parquet as pq

from mjtrial import provenance
from mjtrial.benchmark.config import BenchmarkTask
from mjtrial.layout import BenchmarkLayout
from mjtrial.stages.states import DEVELOPMENT_RULE, EVALUATION_RULE


@dataclass
class BenchmarkVerdict:
    """What verify found: one line per problem; `checked` files."""

    results: str
    checked: int = 0
    problems: list[str] = field(default_factory=list)

    @property
    def exit_code(self) -> int:
        return 1 if self.problems else 0

    def format(self) -> str:
        lines = [f"problem  {p}" for p in self.problems]
        verdict = "verified" if not self.problems else "NOT verified"
        lines.append(
            f"{verdict}: {self.results}: {self.checked} files checked, "
            f"{len(self.problems)} problems"
        )
        return "\n".join(lines)


def verify_benchmark(
    config: Mapping[str, Any], tasks: Mapping[str, BenchmarkTask], *, repo_root: Path
) -> BenchmarkVerdict:
    """Check the benchmark `config` describes (its tasks as `check_benchmark_config` gave)."""
    repo_root = Path(repo_root)
    layout = BenchmarkLayout.of(config["experiment"])
    verdict = BenchmarkVerdict(layout.root.as_posix())
    bench = config["benchmark"]

    def rel(path: Path) -> str:
        return Path(path).as_posix()

    def stamp_of(path: Path) -> dict[str, Any] | None:
        verdict.checked += 1
        try:
            return provenance.read_stamp(repo_root / path)
        except (OSError, ValueError) as err:
            verdict.problems.append(f"{rel(path)}: missing or unstamped ({err})")
            return None

    def expect_input(stamp, name: str, path: Path, owner: Path) -> None:
        recorded = stamp.get("inputs", {}).get(name)
        if not isinstance(recorded, Mapping) or recorded.get("path") != rel(path):
            got = recorded.get("path") if isinstance(recorded, Mapping) else recorded
            verdict.problems.append(f"{rel(owner)}: read {got!r} as {name}, expected {rel(path)}")
        elif (repo_root / path).exists() and recorded.get("sha256") != provenance.file_sha256(
            repo_root / path
        ):
            verdict.problems.append(f"{rel(owner)}: {rel(path)} changed since it was read")

    for task in tasks:
        development, evaluation = layout.task(task).development_states, layout.task(task).states
        for path, rule in ((development, DEVELOPMENT_RULE), (evaluation, EVALUATION_RULE)):
            stamp = stamp_of(path)
            if stamp is not None and stamp.get("rule") != rule:
                verdict.problems.append(
                    f"{rel(path)}: drawn by {stamp.get('rule')!r}, expected {rule!r}"
                )
        shared = _shared_states(repo_root / development, repo_root / evaluation, tasks[task])
        if shared:
            verdict.problems.append(
                f"{rel(development)}: {shared} state(s) also among the evaluation states"
            )
        for method in bench["methods"]:
            for seed in bench["seeds"]:
                parameters = layout.parameters(task, method, seed)
                stamp = stamp_of(parameters)
                if stamp is not None:
                    expect_input(stamp, "development_states", development, parameters)
                outcome = layout.evaluation(task, method, seed)
                stamp = stamp_of(outcome)
                if stamp is not None:
                    expect_input(stamp, "states", evaluation, outcome)
                    expect_input(stamp, "parameters", parameters, outcome)
    # what reads every run: the summary, and the closest calls (their table and replay file)
    for owner in (layout.summary, layout.closest_calls_table, layout.closest_calls):
        stamp = stamp_of(owner)
        if stamp is None:
            continue
        for task in tasks:
            for method in bench["methods"]:
                for seed in bench["seeds"]:
                    key = f"{task}:{method}:{seed}"
                    for name, path in (
                        ("evaluation", layout.evaluation(task, method, seed)),
                        ("parameters", layout.parameters(task, method, seed)),
                    ):
                        expect_input(stamp, f"{name}:{key}", path, owner)
    stamp = stamp_of(layout.report)
    if stamp is not None:
        expect_input(stamp, "summary", layout.summary, layout.report)
        expect_input(stamp, "closest_calls", layout.closest_calls_table, layout.report)
    return verdict


def _shared_states(development: Path, evaluation: Path, task: BenchmarkTask) -> int:
    """How many development states equal an evaluation state (every parameter equal)."""
    try:
        columns = [p.name for p in task.task.state_parameters]
        dev = pq.read_table(development, columns=columns)
        ev = pq.read_table(evaluation, columns=columns)
    except (OSError, ValueError):
        return 0  # named as missing above

    def rows(table) -> set[tuple[float, ...]]:
        return {tuple(r) for r in np.column_stack([table.column(c).to_numpy() for c in columns])}

    return len(rows(dev) & rows(ev))
