"""The evaluation stage of a benchmark: a trained method's parameters run on the task's
evaluation states, one row per state (the rollout table's columns), paired across methods and
seeds by state id; in shards of the task's `rollout.shard_size` states, gathered in one table.

The evaluation states are refused unless their stamp says the states stage drew them as
evaluation states, and the parameter file is an input of the stamp: the table names the
training it judges. A parameter file that names a policy file (a method that runs one per
training seed) runs it through the policy-file condition path (`conditions.POLICY`), and only
while the file is the one its training recorded.
"""

from __future__ import annotations

import json
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq

from mjtrial import REPO_ROOT, provenance
from mjtrial.design.conditions import POLICY
from mjtrial.stages.rollout import run_shard
from mjtrial.stages.stamping import make_stage_stamp
from mjtrial.stages.states import check_drawn_as


def evaluation_condition(
    record: Mapping[str, Any], evaluate_slice: Mapping[str, Any]
) -> dict[str, Any]:
    """The condition a parameter file (`record`, its JSON) runs on a task's evaluation states;
    named `<method>/seed-<seed>`, nothing recorded; with its policy file, if it names one."""
    return {
        "condition": f"{record['method']}/seed-{record['seed']}",
        "task": evaluate_slice["task"],
        **record["parameters"],
        **({POLICY: record["policy"]["path"]} if "policy" in record else {}),
        "failure_taxonomy": dict(evaluate_slice.get("failure_taxonomy", {})),
        "recording": {"rate_hz": 0, "episodes": "none"},
    }


def changed_policy_files(record: Mapping[str, Any], repo_root: Path) -> list[str]:
    """The policy files (graph, contract, external data) a parameter record names whose sha256
    is not the one it records: edited since the training (a missing file counts)."""
    policy = record.get("policy")
    if not policy:
        return []
    changed = []
    for path, sha in (
        (policy["path"], policy["sha256"]),
        (policy["contract"], policy["contract_sha256"]),
        *policy.get("data", {}).items(),
    ):
        file = Path(repo_root) / path
        if not file.is_file() or provenance.file_sha256(file) != sha:
            changed.append(path)
    return changed


def evaluate_method(
    *,
    states: Path,
    parameters: Path,
    model_file: Path,
    evaluate_slice: Mapping[str, Any],
    output: Path,
    first: int = 0,
    stop: int | None = None,
    nthread: int = 0,
    rule: str = "evaluate",
    repo_root: Path = REPO_ROOT,
) -> pa.Table:
    """Run the parameters of `parameters` on the states of `states` with ids in [first, stop)
    (default: every state); write their rows, the table `output`.

    `evaluate_slice`: `task`, `failure_taxonomy` (what the training does not decide).
    """
    check_drawn_as(Path(states), development=False, reader="an evaluation job")
    record = json.loads(Path(parameters).read_text(encoding="utf-8"))
    changed = changed_policy_files(record, repo_root)
    if changed:
        raise ValueError(
            f"{parameters}: {changed[0]} is not the file its training recorded (sha256 differs); "
            "expected it unchanged, or the training rerun"
        )
    stop = pq.read_metadata(states).num_rows if stop is None else stop
    return run_shard(
        condition_slice=evaluation_condition(record, evaluate_slice),
        states_path=Path(states),
        model_file=Path(model_file),
        first=first,
        stop=stop,
        output_table=Path(output),
        nthread=nthread,
        rule=rule,
        repo_root=repo_root,
        extra_inputs={"parameters": Path(parameters)},
    )


def gather_evaluation(
    *,
    shards: Sequence[Path],
    states: Path,
    parameters: Path,
    output: Path,
    rule: str = "evaluate_gather",
    repo_root: Path = REPO_ROOT,
) -> pa.Table:
    """The evaluation's table from its shards' (in state order): every evaluation state once.
    Its stamp names the states and the parameter file, as each shard's does."""
    tables = [provenance.read_checked_table(p).replace_schema_metadata(None) for p in shards]
    table = pa.concat_tables(tables)
    ids = table.column("state_id").to_numpy()
    n = pq.read_metadata(states).num_rows
    if not np.array_equal(ids, np.arange(n)):
        raise ValueError(
            f"{output}: the shards hold state ids {ids[:3].tolist()}..., expected every "
            f"evaluation state 0..{n - 1} once, in order"
        )
    inputs = {"states": Path(states), "parameters": Path(parameters), "shards": list(shards)}
    stamp = make_stage_stamp(rule, {}, inputs, repo_root=repo_root)
    provenance.write_parquet(table, Path(output), stamp)
    return table
