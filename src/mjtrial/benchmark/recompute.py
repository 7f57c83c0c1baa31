"""Recompute, do not trust the seal: what `mjtrial verify` checks of a benchmark beyond stamps.

A forged `analysis/summary.json` with its report and seal rebuilt passes every check on stamps.
So, as for an experiment (`mjtrial.verify.recompute`), verify rebuilds every derived output from
the evaluation tables with the stage functions themselves, on temporary outputs, and compares:
each evaluation table with its shards', the summary, the closest calls' table (its episodes
re-simulated by the stage) and the report's text. Each parameter file must be the record its
training wrote (the sha256 its stamp holds) and consistent with itself (`record_problems`).
A sample of every evaluation shard's episodes is re-simulated with the trained parameters and
compared with its rows, the sample drawn at verify time from a seed that is printed.

An output whose recorded config slice is not the config's of now is named stale (a rebuild fixes
it), not recomputed: it would differ for that reason alone.
"""

from __future__ import annotations

import json
import tempfile
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq

from mjtrial import provenance
from mjtrial.benchmark.config import (
    BenchmarkTask,
    benchmark_runs,
    closest_calls_slice,
    evaluate_slice,
    evaluation_shard_range,
    evaluation_shards,
    summary_slice,
    train_slice,
)
from mjtrial.benchmark.report import benchmark_report
from mjtrial.files.layout import BenchmarkLayout
from mjtrial.stages.benchmark import write_summary
from mjtrial.stages.closest_calls import write_closest_calls
from mjtrial.stages.evaluate import evaluation_condition
from mjtrial.stages.rollout import (
    condition_batches,
    condition_task,
    read_state_values,
    rollout_columns,
)
from mjtrial.stages.train import record_sha256
from mjtrial.verify.differences import json_difference, markdown_difference, table_difference

__all__ = ["BenchmarkRecomputation", "recompute_benchmark", "record_problems"]


@dataclass
class BenchmarkRecomputation:
    """What the recomputation found: one line per problem, and what it did."""

    problems: list[str] = field(default_factory=list)
    recomputed: int = 0
    resimulated: int = 0
    sample_seed: int | None = None

    def line(self) -> str:
        sample = f" (sample seed {self.sample_seed})" if self.resimulated else ""
        return (
            f"recomputed {self.recomputed} outputs from the evaluation tables and re-simulated "
            f"{self.resimulated} evaluation episodes{sample}"
        )


def _same(a: Any, b: Any) -> bool:
    """Equal as JSON gives them back (tuples as lists)."""
    return json.dumps(a, sort_keys=True) == json.dumps(json.loads(json.dumps(b)), sort_keys=True)


def record_problems(record: Mapping[str, Any], train: Mapping[str, Any]) -> list[str]:
    """Why a parameter file's record is not what a training of the slice `train` chooses.

    Consistent means: a method that tunes nothing runs the slice's fixed values (the benchmark's
    condition under the method's `fixed`) and nothing else, with the seed's policy file if the
    slice names one; a method that tunes runs those
    fixed values with the parameters of its best finalist (the first of highest score, the
    tuning's final choice), `score_on_development` is that finalist's score, and the record's
    `fixed` and `tuned` are the slice's.
    """
    method = train["method"]
    tune = {k: [float(b) for b in v] for k, v in method.get("tune", {}).items()}
    fixed = {**train.get("condition", {}), **method.get("fixed", {})}
    fixed = {k: float(v) for k, v in fixed.items() if k not in tune}
    parameters = record.get("parameters")
    if not tune:
        if not _same(parameters, fixed):
            return [f"parameters {parameters} are not the method's fixed values {fixed}"]
        named = (record.get("policy") or {}).get("path")
        if named != method.get("policy"):
            return [f"policy {named!r} is not the seed's policy file {method.get('policy')!r}"]
        return []
    problems = []
    if not _same(record.get("fixed"), fixed) or not _same(record.get("tuned"), tune):
        problems.append(f"fixed and tuned are not the config's ({fixed}, tuned {tune})")
    finalists = record.get("finalists") or []
    if not finalists:
        return [*problems, "no finalists: the final choice cannot be checked"]
    best = max(finalists, key=lambda f: f["score"])  # the first of equals, as the tuning
    if not _same(parameters, {**fixed, **best["parameters"]}):
        problems.append(
            f"parameters {parameters} are not its best finalist's ({best['origin']}: "
            f"{best['parameters']} with the fixed values)"
        )
    if record.get("score_on_development") != best["score"]:
        problems.append(
            f"score_on_development {record.get('score_on_development')} is not its best "
            f"finalist's {best['score']}"
        )
    return problems


class _Recompute:
    def __init__(
        self,
        config: Mapping[str, Any],
        tasks: Mapping[str, BenchmarkTask],
        repo_root: Path,
        found: BenchmarkRecomputation,
    ) -> None:
        self.config, self.tasks, self.repo_root, self.found = config, tasks, repo_root, found
        self.layout = BenchmarkLayout.of(config["experiment"])
        self.runs = benchmark_runs(config)

    def path(self, rel: Path) -> Path:
        return self.repo_root / rel

    def check(self, output: Path, difference: Callable[[], str | None]) -> None:
        """Name `output` when `difference` says why it is not its recomputation."""
        self.found.recomputed += 1
        try:
            why = difference()
        except Exception as err:  # noqa: BLE001 - an output that cannot be rebuilt is named
            why = f"cannot be recomputed ({type(err).__name__}: {' '.join(str(err).split())[:160]})"
        if why:
            self.found.problems.append(
                f"{output.as_posix()}: differs from its recomputation: {why}"
            )

    def is_current(self, output: Path, expected_slice: Any) -> bool:
        """Whether `output` was built with the config slice of now (else it is named stale)."""
        recorded = provenance.read_stamp(self.path(output)).get("config_slice")
        if _same(recorded, expected_slice):
            return True
        self.found.problems.append(
            f"{output.as_posix()}: stale, built with another config slice than the config's "
            "of now; rebuild it (snakemake -c2 --configfile ...)"
        )
        return False

    def parameters(self) -> None:
        for task, method, seed in self.runs:
            rel = self.layout.parameters(task, method, seed)
            obj = json.loads(provenance.read_output_text(self.path(rel)))
            stamp = obj.get("provenance", {})
            recorded = stamp.get("extra", {}).get("record_sha256")
            if recorded is None:
                self.found.problems.append(
                    f"{rel.as_posix()}: its training stamp records no sha256 of the file's "
                    "record (trained before verify checked it); rebuild it"
                )
            elif recorded != record_sha256(obj):
                self.found.problems.append(
                    f"{rel.as_posix()}: edited after training (its record's sha256 is not the "
                    "one its training stamp holds)"
                )
            expected = train_slice(self.config, self.tasks, task, method, int(seed))
            if not self.is_current(rel, expected):
                continue
            for why in record_problems(obj, expected):
                self.found.problems.append(f"{rel.as_posix()}: {why}")

    def gathered(self) -> None:
        for task, method, seed in self.runs:
            shards = [
                self.path(self.layout.evaluation_shard(task, method, seed, s))
                for s in evaluation_shards(self.tasks, task)
            ]
            rel = self.layout.evaluation(task, method, seed)

            def difference(shards: list[Path] = shards, rel: Path = rel) -> str | None:
                parts = [pq.read_table(p) for p in shards]
                expected = {
                    c: np.concatenate([t.column(c).to_numpy(zero_copy_only=False) for t in parts])
                    for c in parts[0].column_names
                }
                return table_difference(
                    pq.read_table(self.path(rel)), expected, what="rows of its shards"
                )

            self.check(rel, difference)

    def derived(self, scratch: Path) -> None:
        """The summary, the closest calls' table and the report, rebuilt by their stages."""
        layout = self.layout
        models = {t: self.path(Path(b.config["model"])) for t, b in self.tasks.items()}
        keys = {f"{t}:{m}:{s}": (t, m, s) for t, m, s in self.runs}
        evaluations = {k: self.path(layout.evaluation(*r)) for k, r in keys.items()}
        parameters = {k: self.path(layout.parameters(*r)) for k, r in keys.items()}
        summary, table = scratch / "summary.json", scratch / "closest_calls.parquet"
        summary_now = summary_slice(self.config)
        if self.is_current(layout.summary, summary_now):
            self.check(
                layout.summary,
                lambda: json_difference(
                    self.path(layout.summary),
                    write_summary(
                        solvability={t: self.path(layout.solvability(t)) for t in self.tasks},
                        evaluations=evaluations,
                        parameters=parameters,
                        summary_slice=summary_now,
                        output=summary,
                        repo_root=self.repo_root,
                    ),
                ),
            )
        closest_now = closest_calls_slice(self.config, self.tasks)
        if self.is_current(layout.closest_calls_table, closest_now):
            self.check(
                layout.closest_calls_table,
                lambda: _rows_difference(
                    pq.read_table(self.path(layout.closest_calls_table)),
                    write_closest_calls(
                        closest_slice=closest_now,
                        states={t: self.path(layout.task(t).states) for t in self.tasks},
                        models=models,
                        evaluations=evaluations,
                        parameters=parameters,
                        output_rrd=scratch / "closest_calls.rrd",
                        output_table=table,
                        repo_root=self.repo_root,
                    ),
                ),
            )
        if summary.is_file() and table.is_file():  # the report from the recomputed two
            self.check(
                layout.report,
                lambda: markdown_difference(
                    self.path(layout.report),
                    benchmark_report(
                        json.loads(summary.read_text(encoding="utf-8")),
                        pq.read_table(table).to_pylist(),
                    ),
                ),
            )

    def resimulate(self, k: int, rng: np.random.Generator) -> None:
        """`k` episodes of every evaluation shard, re-simulated with its parameter file."""
        for task, method, seed in self.runs:
            evaluate = evaluate_slice(self.tasks, task)
            record = json.loads(
                self.path(self.layout.parameters(task, method, seed)).read_text(encoding="utf-8")
            )
            condition = evaluation_condition(record, evaluate)
            model = self.path(Path(self.tasks[task].config["model"]))
            for shard in evaluation_shards(self.tasks, task):
                first, stop = evaluation_shard_range(self.tasks, task, shard)
                ids = sorted(rng.choice(np.arange(first, stop), min(k, stop - first), False))
                rel = self.layout.evaluation_shard(task, method, seed, shard)
                self.check(
                    rel,
                    lambda c=condition, r=rel, i=ids, m=model, t=task: self.resimulated(
                        c, m, self.layout.task(t).states, r, [int(x) for x in i]
                    ),
                )

    def resimulated(
        self, condition: Mapping[str, Any], model: Path, states: Path, rel: Path, ids: list[int]
    ) -> str | None:
        table = pq.read_table(self.path(rel))
        rows = {sid: i for i, sid in enumerate(table.column("state_id").to_pylist())}
        missing = [i for i in ids if i not in rows]
        if missing:
            return f"no row for states {missing[:3]}"
        bound = condition_task(condition, model, repo_root=self.repo_root)
        every = read_state_values(self.path(states), bound.task)
        values = {c: v[ids] for c, v in every.items()}
        columns = rollout_columns(bound.task)
        outcome: dict[str, list[np.ndarray]] = {c: [] for c in columns}
        for batch in condition_batches(bound, condition, values, nthread=1):
            outcome["state_id"].append(batch.values["state_id"])
            for c in columns[1:]:
                outcome[c].append(batch.outcome[c])
        self.found.resimulated += len(ids)
        return table_difference(
            table.take(pa.array([rows[i] for i in ids])),
            {c: np.concatenate(v) for c, v in outcome.items()},
            what="re-simulated episodes",
        )


def _rows_difference(have: pa.Table, want: pa.Table) -> str | None:
    """Why a table's rows are not `want`'s (the first differing row), or None."""
    a, b = have.to_pylist(), want.to_pylist()
    if a == b:
        return None
    if len(a) != len(b):
        return f"{len(a)} rows, {len(b)} recomputed"
    i = next(i for i, (x, y) in enumerate(zip(a, b, strict=True)) if x != y)
    differ = [c for c in a[i] if a[i][c] != b[i].get(c)]
    shown = ", ".join(f"{c} {a[i][c]!r} -> {b[i].get(c)!r}" for c in differ[:3])
    return f"row {i + 1}: {shown} (file -> recomputed)"


def recompute_benchmark(
    config: Mapping[str, Any],
    tasks: Mapping[str, BenchmarkTask],
    *,
    repo_root: Path,
    resimulate: int,
    sample_seed: int | None = None,
) -> BenchmarkRecomputation:
    """Recompute the benchmark's derived outputs and re-simulate `resimulate` episodes of every
    evaluation shard, drawn from `sample_seed` (None: a fresh seed, recorded in the result).

    Run on a folder whose files are all there (verify names a missing one first)."""
    found = BenchmarkRecomputation()
    checker = _Recompute(config, tasks, Path(repo_root), found)
    checker.parameters()
    checker.gathered()
    with tempfile.TemporaryDirectory(prefix="mjtrial-verify-") as scratch:
        checker.derived(Path(scratch))
    if resimulate > 0:
        if sample_seed is None:
            sample_seed = int(np.random.SeedSequence().generate_state(1)[0])
        found.sample_seed = sample_seed
        checker.resimulate(resimulate, np.random.default_rng(sample_seed))
    return found
