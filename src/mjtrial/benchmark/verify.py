"""Verify a benchmark's results: the split between development and evaluation states held, and
every file is the one the next job read.

Checked from the files alone (any machine the folder is copied to): each task's development
and evaluation states were drawn as such (their stamps' rules) and share no state; each
training's stamp names the task's development states, with their sha256 of now; each
evaluation's stamp names the task's evaluation states and the parameter file, with their
sha256 of now; the stamps of the summary and of the closest calls (table and replay file) name
every evaluation and parameter file as they are; the report's names the summary and the
closest calls' table. A training that read anything but its development states fails. A
policy file (graph or contract) a training or an evaluation read is named when it is not, now,
the file its stamp records: it was edited after the run.

Then every derived output is recomputed from the evaluation tables, each parameter file checked
against its training's record of it, and a sample of evaluation episodes re-simulated
(`mjtrial.benchmark.recompute`). And, as for an experiment, the seal lists every output with
its sha256 of now (the report and its figures, which nothing after them records, included),
and the crate is what the folder gives (`mjtrial.crate.check`).
"""

from __future__ import annotations

import json
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow.parquet as pq

from mjtrial import provenance
from mjtrial.benchmark.config import BenchmarkTask, benchmark_runs, evaluation_shards
from mjtrial.benchmark.recompute import recompute_benchmark
from mjtrial.crate.check import covered_seals, crate_differences
from mjtrial.crate.record import input_records
from mjtrial.crate.stamp import read_crate_stamp
from mjtrial.files.layout import BenchmarkLayout
from mjtrial.stages.states import states_rule
from mjtrial.verify.contracts import contract_change
from mjtrial.verify.recompute import DEFAULT_RESIMULATE


@dataclass
class BenchmarkVerdict:
    """What verify found: one line per problem; `checked` files."""

    results: str
    checked: int = 0
    problems: list[str] = field(default_factory=list)
    checks: list[str] = field(default_factory=list)  # what was recomputed, in one line each

    @property
    def exit_code(self) -> int:
        return 1 if self.problems else 0

    def format(self) -> str:
        lines = [f"problem  {p}" for p in self.problems] + [f"checked  {c}" for c in self.checks]
        verdict = "verified" if not self.problems else "NOT verified"
        lines.append(
            f"{verdict}: {self.results}: {self.checked} files checked, "
            f"{len(self.problems)} problems"
        )
        return "\n".join(lines)


def verify_benchmark(
    config: Mapping[str, Any],
    tasks: Mapping[str, BenchmarkTask],
    *,
    repo_root: Path,
    resimulate: int = DEFAULT_RESIMULATE,
    sample_seed: int | None = None,
) -> BenchmarkVerdict:
    """Check the benchmark `config` describes (its tasks as `check_benchmark_config` gave),
    re-simulating `resimulate` episodes of every evaluation shard (drawn from `sample_seed`,
    None: a fresh one, printed)."""
    repo_root = Path(repo_root)
    layout = BenchmarkLayout.of(config["experiment"])
    verdict = BenchmarkVerdict(layout.root.as_posix())

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

    named: set[str] = set()

    def policies_of(task: str, method: str) -> bool:
        return method in tasks[task].policies

    def policy_changed(stamp, owner: Path) -> None:
        """Each policy file the stamp records, as it is now: edited after the run, it is
        named once."""
        records = stamp.get("inputs", {}).get("policy", [])
        shadowed = contract_change(records, repo_root=repo_root) if records else None
        if shadowed and shadowed not in named:
            named.add(shadowed)
            verdict.problems.append(f"{shadowed}; rerun what uses it ({rel(owner)} ran with it)")
        for record in records:
            path = record.get("path") if isinstance(record, Mapping) else None
            if path is None or path in named:
                continue
            file = repo_root / path
            if not file.is_file() or provenance.file_sha256(file) != record.get("sha256"):
                named.add(path)
                verdict.problems.append(
                    f"{path}: policy file changed since the run ({rel(owner)} read it with "
                    f"sha256 {str(record.get('sha256'))[:12]}); rerun what uses it"
                )

    for task in tasks:
        development, evaluation = layout.task(task).development_states, layout.task(task).states
        for path, rule in (
            (development, states_rule(development=True, task=task)),
            (evaluation, states_rule(development=False, task=task)),
        ):
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
    runs = benchmark_runs(config)
    for task, method, seed in runs:
        parameters = layout.parameters(task, method, seed)
        stamp = stamp_of(parameters)
        if stamp is not None:
            expect_input(
                stamp, "development_states", layout.task(task).development_states, parameters
            )
            policy_changed(stamp, parameters)
        outcome = layout.evaluation(task, method, seed)
        stamp = stamp_of(outcome)
        if stamp is not None:
            expect_input(stamp, "states", layout.task(task).states, outcome)
            expect_input(stamp, "parameters", parameters, outcome)
        for shard in evaluation_shards(tasks, task) if policies_of(task, method) else ():
            path = layout.evaluation_shard(task, method, seed, shard)
            stamp = stamp_of(path)
            if stamp is not None:
                policy_changed(stamp, path)
    # what reads every run: the summary, and the closest calls (their table and replay file)
    for owner in (layout.summary, layout.closest_calls_table, layout.closest_calls):
        stamp = stamp_of(owner)
        if stamp is None:
            continue
        for task, method, seed in runs:
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
    outputs = layout.benchmark_outputs(
        [(t, m, str(s)) for t, m, s in runs], {t: evaluation_shards(tasks, t) for t in tasks}
    )
    verdict.problems += _seal_problems(layout, outputs, repo_root)
    verdict.checked += 1
    if all((repo_root / p).is_file() for p in outputs):  # a missing one is named above
        found = recompute_benchmark(
            config, tasks, repo_root=repo_root, resimulate=resimulate, sample_seed=sample_seed
        )
        verdict.problems += found.problems
        verdict.checks.append(found.line())
    if not verdict.problems:  # the crate is rebuilt from a folder whose chain holds
        verdict.problems += _crate_problems(layout, repo_root)
        verdict.checked += 1
    return verdict


def _seal_problems(layout: BenchmarkLayout, outputs: list[Path], repo_root: Path) -> list[str]:
    """Every output listed in the seal with its sha256 of now, and the seal as stamped."""
    seal = layout.seal.as_posix()
    try:
        listed = json.loads(provenance.read_output_text(repo_root / seal))["outputs"]
        stamped = {
            r["path"]: r["sha256"]
            for r in input_records(provenance.read_stamp(repo_root / seal)["inputs"])
        }
    except (OSError, ValueError, KeyError, TypeError) as err:
        return [f"{seal}: missing or unreadable ({err})"]
    if listed != stamped:
        return [f"{seal}: its list of outputs is not the one its stamp records"]
    problems = []
    for output in (p.as_posix() for p in outputs):
        if output not in listed:
            problems.append(f"{seal}: does not list {output}")
        elif not (repo_root / output).exists():
            problems.append(f"{output}: missing (sealed in {seal})")
        elif provenance.file_sha256(repo_root / output) != listed[output]:
            problems.append(f"{output}: changed since it was sealed ({seal})")
    return problems


def _crate_problems(layout: BenchmarkLayout, repo_root: Path) -> list[str]:
    """The crate covers the seal as it is, and is what the folder gives."""
    crate = layout.crate.as_posix()
    if not (repo_root / crate).is_file():
        return [f"{crate}: missing"]
    stamp = read_crate_stamp(repo_root / crate)
    if stamp is None or covered_seals(stamp) != [layout.seal.as_posix()]:
        return [f"{crate}: its stamp does not record {layout.seal.as_posix()} as its one seal"]
    recorded = next(iter(input_records(stamp["inputs"])))["sha256"]
    if recorded != provenance.file_sha256(repo_root / layout.seal):
        return [f"{crate}: written from another {layout.seal.as_posix()} than the one there"]
    differs = crate_differences(layout, repo_root=repo_root, stamps={})
    return [f"{path}: {reason}" for path, reason in differs.items()]


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
