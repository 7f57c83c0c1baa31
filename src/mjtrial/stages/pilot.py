"""The pilot: the design's conditions on the development states, before the evaluation runs.

`snakemake -c2 pilot` rolls out every condition on the development states into
`development/` (`Layout.development`, laid out as an experiment's: shard tables, each
condition's table, its nominal episode) and writes the rates with their Wilson intervals
(`Layout.pilot_summary`): what a researcher tunes gains or thresholds on. No falsifier is judged,
nothing is recorded, and no stage of the evaluation reads any of it: each pilot job refuses
states not drawn as development states, and the analysis refuses the pilot's tables
(`stages.states.check_evaluation_table`).
"""

from __future__ import annotations

import logging
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import pyarrow as pa
import pyarrow.parquet as pq

from mjtrial import REPO_ROOT, analysis, provenance
from mjtrial.design.conditions import condition_record
from mjtrial.stages.rollout import run_shard
from mjtrial.stages.stamping import make_stage_stamp, task_inputs
from mjtrial.stages.states import check_drawn_as
from mjtrial.task import load_task

log = logging.getLogger("mjtrial")

# What the pilot's summary says it is, in its own words.
PILOT_NOTE = (
    "a pilot on the development states: rates to tune on, no falsifier judged; "
    "no reported number reads them"
)


def run_pilot_shard(
    *,
    condition_slice: Mapping[str, Any],
    states_path: Path,
    model_file: Path,
    first: int,
    stop: int,
    output_table: Path,
    nthread: int,
    rule: str,
    repo_root: Path = REPO_ROOT,
) -> pa.Table:
    """One shard of a condition on the development states (`run_shard`, nothing recorded),
    stamped `rule` (`pilot:<condition>#<shard>`); states not drawn as development states are
    refused."""
    check_drawn_as(Path(states_path), development=True, reader="a pilot job")
    return run_shard(
        condition_slice=condition_slice,
        states_path=Path(states_path),
        model_file=Path(model_file),
        first=first,
        stop=stop,
        output_table=Path(output_table),
        nthread=nthread,
        rule=rule,
        repo_root=repo_root,
    )


def summarize_pilot(
    pilot_tables: Mapping[str, Path],
    pilot_slice: Mapping[str, Any],
    *,
    repo_root: Path = REPO_ROOT,
) -> dict[str, Any]:
    """Each condition's settings, successes, n, rate, Wilson interval and unhealthy episodes on
    the development states (`mjtrial.analysis.rate_record`), and failures by category."""
    task = load_task(pilot_slice["task"], repo_root=repo_root)
    confidence = float(pilot_slice["confidence"])
    conditions = {}
    for name, path in pilot_tables.items():
        table = pq.read_table(path)
        columns = {c: table.column(c).to_numpy(zero_copy_only=False) for c in table.column_names}
        conditions[name] = {
            **condition_record(task, pilot_slice["conditions"][name]),
            **analysis.rate_record(columns["success"], confidence=confidence),
            "unhealthy": int(analysis.unhealthy(columns).sum()),
            "failures": analysis.failure_counts(columns["failure_category"], task.category_names()),
        }
    return {
        "pilot": PILOT_NOTE,
        "states": "development",
        "confidence": confidence,
        "interval": "Wilson score",
        "conditions": conditions,
    }


def write_pilot_summary(
    *,
    pilot_tables: Mapping[str, Path],
    pilot_slice: Mapping[str, Any],
    output: Path,
    repo_root: Path = REPO_ROOT,
) -> dict[str, Any]:
    """Write the pilot's summary (`summarize_pilot`), stamped `pilot_summary`, and log it."""
    summary = summarize_pilot(pilot_tables, pilot_slice, repo_root=repo_root)
    inputs = {
        **task_inputs(pilot_slice["task"], repo_root=repo_root),
        **{f"pilot:{k}": Path(v) for k, v in pilot_tables.items()},
    }
    stamp = make_stage_stamp("pilot_summary", dict(pilot_slice), inputs, repo_root=repo_root)
    provenance.write_json(summary, output, stamp)
    lines = [
        f"  {name}: {c['successes']}/{c['n']} = {c['rate']:.3f} "
        f"[{c['wilson_low']:.3f}, {c['wilson_high']:.3f}]"
        for name, c in summary["conditions"].items()
        if c["n"]
    ]
    log.info("pilot (development states, not reported) -> %s\n%s", output, "\n".join(lines))
    return summary
