"""The benchmark's summary and report stages: every evaluation table and parameter file in,
`analysis/summary.json` (mjtrial.benchmark.summary) and `report.md` out."""

from __future__ import annotations

import json
import logging
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq

from mjtrial import REPO_ROOT, provenance
from mjtrial.benchmark.report import benchmark_report
from mjtrial.benchmark.solvability import probe_states
from mjtrial.benchmark.summary import summarize_benchmark
from mjtrial.report.figures import write_benchmark_figures
from mjtrial.sim import engine
from mjtrial.stages.condition import condition_task, thresholds_of
from mjtrial.stages.stamping import make_stage_stamp, model_inputs, task_inputs

log = logging.getLogger("mjtrial")


def _key(task: str, method: str, seed: int) -> str:
    return f"{task}:{method}:{seed}"


def solvability_record(path: Path) -> dict[str, Any]:
    """A task's solvability check for the summary: how it probed, under which reference, how
    many probe states the reference solved, and every one it did not (the unsolvable regions)."""
    table = pq.read_table(path).to_pylist()
    stamp = provenance.read_stamp(path)
    failed = [r for r in table if not r["success"]]
    return {
        "probe": table[0]["probe"] if table else None,
        "reference": stamp["config_slice"]["reference"],
        "n": len(table),
        "solved": len(table) - len(failed),
        "unsolved": [{k: v for k, v in r.items() if k not in ("success", "probe")} for r in failed],
    }


def write_summary(
    *,
    solvability: Mapping[str, Path],
    evaluations: Mapping[str, Path],
    parameters: Mapping[str, Path],
    summary_slice: Mapping[str, Any],
    output: Path,
    repo_root: Path = REPO_ROOT,
) -> dict[str, Any]:
    """`evaluations` and `parameters`: `<task>:<method>:<seed>` -> file, for every task,
    method and seed of `summary_slice` (`tasks`, `methods` with their budgets, `seeds`,
    `headline`, `unequal_budgets`, `analysis`); a method whose entry lists its `tasks` runs
    on those only."""
    tasks, methods, seeds = summary_slice["tasks"], summary_slice["methods"], summary_slice["seeds"]
    outcomes: dict[str, dict[str, dict[int, np.ndarray]]] = {}
    used: dict[str, dict[str, dict[int, int]]] = {}
    for task in tasks:
        outcomes[task], used[task] = {}, {}
        reference_ids = None
        for method in methods:
            if task not in methods[method].get("tasks", tasks):
                continue  # not run on this task: no cell, and the summary says so
            outcomes[task][method], used[task][method] = {}, {}
            for seed in seeds:
                key = _key(task, method, seed)
                table = pq.read_table(evaluations[key], columns=["state_id", "success"])
                ids = table.column("state_id").to_numpy()
                if reference_ids is None:
                    reference_ids = ids
                elif not np.array_equal(ids, reference_ids):  # pairing needs the same states
                    raise ValueError(f"{evaluations[key]}: not the states the other methods ran")
                outcomes[task][method][seed] = table.column("success").to_numpy(
                    zero_copy_only=False
                )
                record = json.loads(Path(parameters[key]).read_text(encoding="utf-8"))
                used[task][method][seed] = int(record["episodes_used"])
    summary = summarize_benchmark(
        outcomes,
        methods=list(methods),
        budgets={m: spec["budget"] for m, spec in methods.items()},
        episodes_used=used,
        headline=summary_slice["headline"],
        unequal_budgets=summary_slice.get("unequal_budgets"),
        analysis=summary_slice["analysis"],
    )
    summary["question"] = summary_slice["question"]
    summary["solvability"] = {task: solvability_record(solvability[task]) for task in tasks}
    summary["method_descriptions"] = {m: spec["description"] for m, spec in methods.items()}
    records = {k: json.loads(Path(p).read_text(encoding="utf-8")) for k, p in parameters.items()}
    summary["tuned_parameters"] = {key: r["parameters"] for key, r in records.items()}
    policies = {key: r["policy"] for key, r in records.items() if "policy" in r}
    if policies:  # each run's policy file, named in the report
        summary["policy_files"] = policies
    inputs = {f"solvability:{k}": Path(v) for k, v in solvability.items()}
    inputs |= {f"evaluation:{k}": Path(v) for k, v in evaluations.items()}
    inputs |= {f"parameters:{k}": Path(v) for k, v in parameters.items()}
    stamp = make_stage_stamp(
        "benchmark",
        dict(summary_slice),
        inputs,
        seeds={"bootstrap": summary_slice["analysis"]["seed"]},
        repo_root=repo_root,
    )
    provenance.write_json(summary, Path(output), stamp)
    log.info("benchmark summary -> %s", output)
    return summary


def write_report(
    *,
    summary: Path,
    closest_calls: Path,
    output: Path,
    figures_dir: Path,
    rule: str = "benchmark_report",
    repo_root: Path = REPO_ROOT,
) -> str:
    """The benchmark's report and figures from its summary and its closest calls' table."""
    data = json.loads(Path(summary).read_text(encoding="utf-8"))
    text = benchmark_report(data, pq.read_table(closest_calls).to_pylist())
    inputs = {"summary": Path(summary), "closest_calls": Path(closest_calls)}
    stamp = make_stage_stamp(rule, {}, inputs, repo_root=repo_root)
    write_benchmark_figures(summary=data, out_dir=Path(figures_dir), stamp=stamp)
    provenance.write_markdown(text, Path(output), stamp)
    log.info("benchmark report -> %s", output)
    return text


def write_solvability(
    *,
    solvability_slice: Mapping[str, Any],
    model_file: Path,
    output: Path,
    nthread: int = 0,
    rule: str = "solvability",
    repo_root: Path = REPO_ROOT,
) -> pa.Table:
    """Run the task's probe states under its reference controller; write their outcomes.

    `solvability_slice`: `task`, `ranges`, `reference` (protocol parameters), `failure_taxonomy`,
    and `max_corner_parameters`, `states`, `seed` (see `probe_states`).
    """
    bound = condition_task(solvability_slice, Path(model_file), repo_root=repo_root)
    parameters = [p.name for p in bound.task.state_parameters]
    how, values = probe_states(
        solvability_slice["ranges"],
        parameters,
        max_corner_parameters=solvability_slice["max_corner_parameters"],
        n_hypercube=solvability_slice["states"],
        seed=solvability_slice["seed"],
    )
    success, category = [], []
    for batch in engine.iter_batches(
        bound,
        values,
        solvability_slice["reference"],
        thresholds=thresholds_of(bound, solvability_slice),
        nthread=nthread,
    ):
        success.append(batch.outcome["success"])
        category.append(batch.outcome["failure_category"])
    table = pa.table(
        {
            **{p: pa.array(values[p]) for p in parameters},
            "success": pa.array(np.concatenate(success)),
            "failure_category": pa.array(np.concatenate(category).tolist(), type=pa.string()),
            "probe": pa.array([how] * len(values[parameters[0]])),
        }
    )
    inputs = {
        **model_inputs(Path(model_file)),
        **task_inputs(solvability_slice["task"], repo_root=repo_root),
    }
    stamp = make_stage_stamp(rule, dict(solvability_slice), inputs, repo_root=repo_root)
    provenance.write_parquet(table, Path(output), stamp)
    log.info(
        "%s: %d of %d probe states (%s) solved by the reference -> %s",
        rule,
        int(table.column("success").to_numpy().sum()),
        table.num_rows,
        how,
        output,
    )
    return table
