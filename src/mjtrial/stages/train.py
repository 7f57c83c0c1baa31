"""The training stage of a benchmark: one method tuned on one task for one training seed, on
the task's development states only, written as a stamped parameter file.

The split is enforced here, not advised: the job reads one states file, and refuses it unless
its stamp says the states stage drew it as development states (`states:development`). The
stamp of the parameter file records that file's sha256, so `mjtrial verify` can check, on any
machine, that no training read an evaluation state; and the sha256 of the parameter file's own
record (`record_sha256`): the evaluations' stamps record the file as they read it, so only this
names a file edited after training and evaluated again.

A method that runs trained policy files (`policy`, one file per training seed) spends no
episode: its record names the seed's file with the sha256 of its graph and contract, and the
evaluation runs that file; both stamps record the two files as inputs.
"""

from __future__ import annotations

import json
import logging
from collections.abc import Mapping
from pathlib import Path
from typing import Any

from mjtrial import REPO_ROOT, provenance
from mjtrial.benchmark.tuning import tune, tuned_parameter_record
from mjtrial.policy_files.file import load_policy_file, policy_inputs
from mjtrial.stages.condition import condition_task, thresholds_of
from mjtrial.stages.rollout import read_state_values
from mjtrial.stages.stamping import make_stage_stamp, model_inputs, task_inputs
from mjtrial.stages.states import check_drawn_as

log = logging.getLogger("mjtrial")


def record_sha256(record: Mapping[str, Any]) -> str:
    """sha256 of a parameter file's record (its JSON without the stamp), as read back."""
    payload = {k: v for k, v in record.items() if k != "provenance"}
    return provenance.config_hash(json.loads(json.dumps(payload)))


def policy_record(path: str, task: Any, repo_root: Path) -> dict[str, str]:
    """What a parameter record says of its policy file: the file (as the config names it) and
    the sha256 of its graph, of its contract and of the graph's external data files (`data`,
    only for a graph that has them), checked against the task."""
    checked = load_policy_file(Path(repo_root) / path, task)
    data = {
        provenance.repo_relative(f, repo_root): provenance.file_sha256(f) for f in checked.data
    }
    return {
        "path": path,
        "sha256": checked.sha256,
        "contract": provenance.repo_relative(checked.contract.source, repo_root),
        "contract_sha256": checked.contract_sha256,
        **({"data": data} if data else {}),
    }


def train_method(
    *,
    development_states: Path,
    model_file: Path,
    train_slice: Mapping[str, Any],
    output: Path,
    nthread: int = 0,
    rule: str = "train",
    repo_root: Path = REPO_ROOT,
) -> dict[str, Any]:
    """Tune the slice's method on its task for its seed; write the parameter file `output`.

    `train_slice`: `task` (the task's reference), `failure_taxonomy`, `condition` (what every
    method runs with), `method` (its name, `budget`, `episodes_per_candidate`, and this
    task's `fixed` and `tune`), `seed` (the training seed), `development_seed`.
    """
    check_drawn_as(Path(development_states), development=True, reader="a training job")
    bound = condition_task(train_slice, Path(model_file), repo_root=repo_root)
    values = read_state_values(Path(development_states), bound.task)
    values.pop("state_id")
    method = train_slice["method"]
    policy = method.get("policy")  # the seed's policy file: nothing to tune
    tuned = {k: tuple(v) for k, v in method.get("tune", {}).items()}
    fixed = {**train_slice.get("condition", {}), **method.get("fixed", {})}
    fixed = {k: float(v) for k, v in fixed.items() if k not in tuned}
    if tuned:
        result = tune(
            bound,
            values,
            tuned=tuned,
            fixed=fixed,
            thresholds=thresholds_of(bound, train_slice),
            budget_episodes=method["budget"],
            episodes_per_candidate=method["episodes_per_candidate"],
            seed=train_slice["seed"],
            nthread=nthread,
        )
        record = tuned_parameter_record(
            result,
            development_seed=train_slice["development_seed"],
            task=bound.task.name,
            method=method["name"],
        )
    else:  # nothing to tune: the parameters as given, no episode spent
        record = {
            "task": bound.task.name,
            "method": method["name"],
            "parameters": dict(fixed),  # the task's defaults for the rest, as tuned ones have
            **(
                {"policy": policy_record(method["policy"], bound.task, repo_root)} if policy else {}
            ),
            "budget_episodes": 0,
            "episodes_used": 0,
            "seed": train_slice["seed"],
        }
    inputs = {
        "development_states": Path(development_states),
        **model_inputs(Path(model_file)),
        **task_inputs(train_slice["task"], repo_root=repo_root),
        **policy_inputs([Path(repo_root) / policy] if policy else []),
    }
    stamp = make_stage_stamp(
        rule,
        dict(train_slice),
        inputs,
        seeds={"training": train_slice["seed"]},
        repo_root=repo_root,
    )
    stamp["extra"]["record_sha256"] = record_sha256(record)
    provenance.write_json(record, Path(output), stamp)
    log.info(
        "train %s on %s, seed %s: %s (%d episodes) -> %s",
        method["name"],
        bound.task.name,
        train_slice["seed"],
        record["parameters"],
        record["episodes_used"],
        output,
    )
    return record
