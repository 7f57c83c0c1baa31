"""The evaluation stage of a benchmark: a trained method's parameters run on the task's
evaluation states, one row per state (the rollout table's columns), paired across methods and
seeds by state id.

The evaluation states are refused unless their stamp says the states stage drew them as
evaluation states, and the parameter file is an input of the stamp: the table names the
training it judges.
"""

from __future__ import annotations

import json
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import pyarrow as pa
import pyarrow.parquet as pq

from mjtrial import REPO_ROOT
from mjtrial.stages.rollout import run_shard
from mjtrial.stages.states import check_drawn_as


def evaluation_condition(
    record: Mapping[str, Any], evaluate_slice: Mapping[str, Any]
) -> dict[str, Any]:
    """The condition a parameter file (`record`, its JSON) runs on a task's evaluation states;
    named `<method>/seed-<seed>`, nothing recorded."""
    return {
        "condition": f"{record['method']}/seed-{record['seed']}",
        "task": evaluate_slice["task"],
        **record["parameters"],
        "failure_taxonomy": dict(evaluate_slice.get("failure_taxonomy", {})),
        "recording": {"rate_hz": 0, "episodes": "none"},
    }


def evaluate_method(
    *,
    states: Path,
    parameters: Path,
    model_file: Path,
    evaluate_slice: Mapping[str, Any],
    output: Path,
    nthread: int = 0,
    rule: str = "evaluate",
    repo_root: Path = REPO_ROOT,
) -> pa.Table:
    """Run the parameters of `parameters` on every state of `states`; write the table `output`.

    `evaluate_slice`: `task`, `failure_taxonomy` (what the training does not decide).
    """
    check_drawn_as(Path(states), development=False, reader="an evaluation job")
    record = json.loads(Path(parameters).read_text(encoding="utf-8"))
    n = pq.read_metadata(states).num_rows
    return run_shard(
        condition_slice=evaluation_condition(record, evaluate_slice),
        states_path=Path(states),
        model_file=Path(model_file),
        first=0,
        stop=n,
        output_table=Path(output),
        nthread=nthread,
        rule=rule,
        repo_root=repo_root,
        extra_inputs={"parameters": Path(parameters)},
    )
