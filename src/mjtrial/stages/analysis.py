"""The analysis stage: the summary of every condition, the paired comparison, the verdict."""

from __future__ import annotations

import json
import logging
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import pyarrow.parquet as pq

from mjtrial import REPO_ROOT, analysis, provenance
from mjtrial.design import registration
from mjtrial.design.conditions import condition_record
from mjtrial.stages.stamping import make_stage_stamp, task_inputs
from mjtrial.stages.states import check_drawn_as, check_evaluation_table
from mjtrial.stats import sequential
from mjtrial.task import load_task

log = logging.getLogger("mjtrial")


def run_analysis(
    *,
    states_path: Path,
    rollout_tables: Mapping[str, Path],
    nominal_files: Mapping[str, Path],
    analysis_slice: Mapping[str, Any],
    output: Path,
    repo_root: Path = REPO_ROOT,
    registration_path: Path | None = None,
) -> dict[str, Any]:
    """Compute the summary, write `summary.json`, and log the table.

    Only the evaluation's states and tables are read: development states or a pilot's table
    (`snakemake -c2 pilot`) are refused, whatever their path. A registration
    (`registration_path`, when the file exists) is an input: a comparison it did not plan is
    marked exploratory."""
    check_drawn_as(Path(states_path), development=False, reader="the analysis")
    for path in rollout_tables.values():
        check_evaluation_table(Path(path), reader="the analysis")
    summary = summarize_tables(
        states_path=states_path,
        rollout_tables=rollout_tables,
        nominal_files=nominal_files,
        analysis_slice=analysis_slice,
        repo_root=repo_root,
        registration_path=registration_path,
    )
    inputs = {
        "states": states_path,
        **task_inputs(analysis_slice["task"], repo_root=repo_root),
        **{f"rollout:{k}": v for k, v in rollout_tables.items()},
    }
    inputs |= {f"nominal:{k}": v for k, v in nominal_files.items()}
    if registration_path is not None and Path(registration_path).is_file():
        inputs[REGISTRATION_INPUT] = registration_path
    stamp = make_stage_stamp(
        "analysis",
        dict(analysis_slice),
        inputs,
        seeds={"bootstrap": analysis_slice["analysis"]["seed"]},
        repo_root=repo_root,
    )
    provenance.write_json(summary, output, stamp)
    log.info("analysis -> %s\n%s", output, analysis.format_table(summary))
    return summary


def summarize_tables(
    *,
    states_path: Path,
    rollout_tables: Mapping[str, Path],
    nominal_files: Mapping[str, Path],
    analysis_slice: Mapping[str, Any],
    repo_root: Path = REPO_ROOT,
    registration_path: Path | None = None,
) -> dict[str, Any]:
    """The summary the analysis stage writes, from its input files (`mjtrial verify` checks
    `summary.json` against it)."""
    conditions = analysis_slice["conditions"]
    task = load_task(analysis_slice["task"], repo_root=repo_root)
    analysis_config = analysis_slice["analysis"]
    states_table = pq.read_table(states_path)
    states = {c: states_table.column(c).to_numpy() for c in states_table.column_names}
    outcomes = {}
    for name, path in rollout_tables.items():
        t = pq.read_table(path)
        outcomes[name] = {c: t.column(c).to_numpy(zero_copy_only=False) for c in t.column_names}
    nominal = {
        name: bool(json.loads(Path(p).read_text())["success"]) for name, p in nominal_files.items()
    }
    stopping = analysis_slice.get("stopping")
    if stopping:  # a stopping rule ran the first n states only (mjtrial.stats.sequential)
        n = min(len(table["state_id"]) for table in outcomes.values())
        keep = states["state_id"] < n
        states = {c: values[keep] for c, values in states.items()}
    record = None
    if stopping:
        falsifier = analysis_slice["falsifier"]
        record = sequential.stopping_record(
            outcomes[falsifier["treatment"]]["success"],
            outcomes[falsifier["baseline"]]["success"],
            stopping=stopping,
        )
    return analysis.summarize(
        states=states,
        outcomes=outcomes,
        nominal=nominal,
        condition_parameters={name: condition_record(task, c) for name, c in conditions.items()},
        nominal_text=task.nominal_description,
        categories=task.category_names(),
        falsifier=analysis_slice["falsifier"],
        analysis=analysis_config,
        sample_size=analysis_slice.get("sample_size"),
        registered=read_registration(registration_path),
        stopping=record,
    )


# The stamp's name for the registration among the analysis' inputs (verify passes it back).
REGISTRATION_INPUT = "registration"


def read_registration(path: Path | None) -> Mapping[str, Any] | None:
    """The registered config's sections (`registration.json`'s current design, as
    `mjtrial.design.registration` writes it), or None when nothing is registered: then no comparison
    is exploratory."""
    if path is None or not Path(path).is_file():
        return None
    return registration.read(Path(path))["current"]["design"]["sections"]
