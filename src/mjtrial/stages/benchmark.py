"""The benchmark's summary and report stages: every evaluation table and parameter file in,
`analysis/summary.json` (mjtrial.benchmark.summary) and `report.md` out."""

from __future__ import annotations

import json
import logging
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow.parquet as pq

from mjtrial import REPO_ROOT, provenance
from mjtrial.benchmark.report import benchmark_report
from mjtrial.benchmark.summary import summarize_benchmark
from mjtrial.stages.stamping import make_stage_stamp

log = logging.getLogger("mjtrial")


def _key(task: str, method: str, seed: int) -> str:
    return f"{task}:{method}:{seed}"


def write_summary(
    *,
    evaluations: Mapping[str, Path],
    parameters: Mapping[str, Path],
    summary_slice: Mapping[str, Any],
    output: Path,
    repo_root: Path = REPO_ROOT,
) -> dict[str, Any]:
    """`evaluations` and `parameters`: `<task>:<method>:<seed>` -> file, for every task,
    method and seed of `summary_slice` (`tasks`, `methods` with their budgets, `seeds`,
    `headline`, `unequal_budgets`, `analysis`)."""
    tasks, methods, seeds = summary_slice["tasks"], summary_slice["methods"], summary_slice["seeds"]
    outcomes: dict[str, dict[str, dict[int, np.ndarray]]] = {}
    used: dict[str, dict[str, dict[int, int]]] = {}
    for task in tasks:
        outcomes[task], used[task] = {}, {}
        reference_ids = None
        for method in methods:
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
        budgets={m: spec["budget"] for m, spec in methods.items()},
        episodes_used=used,
        headline=summary_slice["headline"],
        unequal_budgets=summary_slice.get("unequal_budgets"),
        analysis=summary_slice["analysis"],
    )
    summary["question"] = summary_slice["question"]
    summary["method_descriptions"] = {m: spec["description"] for m, spec in methods.items()}
    summary["tuned_parameters"] = {
        key: json.loads(Path(path).read_text(encoding="utf-8"))["parameters"]
        for key, path in parameters.items()
    }
    inputs = {f"evaluation:{k}": Path(v) for k, v in evaluations.items()}
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
    *, summary: Path, output: Path, rule: str = "benchmark_report", repo_root: Path = REPO_ROOT
) -> str:
    """The benchmark's report from its summary."""
    data = json.loads(Path(summary).read_text(encoding="utf-8"))
    text = benchmark_report(data)
    stamp = make_stage_stamp(rule, {}, {"summary": Path(summary)}, repo_root=repo_root)
    provenance.write_markdown(text, Path(output), stamp)
    log.info("benchmark report -> %s", output)
    return text
