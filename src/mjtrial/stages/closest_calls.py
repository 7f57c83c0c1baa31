"""The benchmark's closest calls: for each task, the successes of smallest margin and the
episodes of largest margin over every method and training seed, re-simulated with their
trajectories into `replay/closest_calls.rrd`, listed in `replay/closest_calls.parquet`.

A task that declares no margin has none. Runs whose parameters and policy file are equal (a
method that tunes nothing and runs no file of its own per seed, under every seed) ran the same
episodes: only the first seed's are candidates. Each
chosen episode is re-simulated alone and must reproduce its evaluation row's success and margin
exactly, else the stage fails: the file shows the episodes the tables scored.
"""

from __future__ import annotations

import json
import logging
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq

from mjtrial import REPO_ROOT, provenance
from mjtrial.closest_calls import choose, margins
from mjtrial.policy_files.file import policy_inputs
from mjtrial.recording.failures import write_episodes_rrd
from mjtrial.recording.names import (
    CLOSEST_CALLS_PREFIX,
    CLOSEST_CALLS_SUMMARY,
    episode_recording_id,
)
from mjtrial.recording.write import EpisodeStores
from mjtrial.sim import engine
from mjtrial.stages.evaluate import evaluation_condition
from mjtrial.stages.rollout import (
    condition_batches,
    condition_parameters,
    condition_policy_inputs,
    condition_task,
    episode_records,
    read_state_values,
    recording_spec,
)
from mjtrial.stages.stamping import make_stage_stamp, model_inputs, task_inputs

log = logging.getLogger("mjtrial")

COLUMNS = (
    "task",
    "kind",
    "rank",
    "method",
    "seed",
    "state_id",
    "success",
    "margin",
    "margin_measure",
    "failure_category",
    "recording_id",
)


def _condition_name(task: str, method: str, seed: int) -> str:
    return f"{task}.{method}.seed-{seed}"


def _candidates(
    runs: Sequence[tuple[str, int]], parameters: Mapping[tuple[str, int], Path]
) -> list[tuple[str, int]]:
    """The runs whose episodes are candidates: the first of each set of equal parameters
    (and policy file: a method's training seeds' files differ)."""
    seen, kept = set(), []
    for run in runs:
        record = json.loads(Path(parameters[run]).read_text(encoding="utf-8"))
        key = json.dumps([record["parameters"], record.get("policy")], sort_keys=True)
        if key not in seen:
            seen.add(key)
            kept.append(run)
    return kept


def _task_calls(
    task_name: str,
    spec: Mapping[str, Any],
    *,
    k: int,
    states: Path,
    model: Path,
    evaluations: Mapping[tuple[str, int], Path],
    parameters: Mapping[tuple[str, int], Path],
    rule: str,
    repo_root: Path,
) -> tuple[list[dict[str, Any]], list[tuple[EpisodeStores, list[Any]]]]:
    """One task's closest calls: their table rows, and per run the recordings' builder and the
    re-simulated episodes (`evaluations`, `parameters`: (method, seed) -> file)."""
    bound = condition_task(spec["evaluate_slice"], model, repo_root=repo_root)
    task = bound.task
    if task.margin is None:
        log.info("%s: %s declares no margin: no closest calls", rule, task_name)
        return [], []
    candidates, tables, margin_parts = [], [], []
    for run in _candidates(list(evaluations), parameters):
        record = json.loads(parameters[run].read_text(encoding="utf-8"))
        condition = evaluation_condition(record, spec["evaluate_slice"])
        params = task.parameters(condition_parameters(bound, condition))
        table = pq.read_table(evaluations[run])
        where = f"{evaluations[run].name} of {task_name}/{run[0]}"
        source = str(task.source or task.name)
        margin_parts.append(margins(task.margin, table, params, source=source, where=where))
        tables.append(table)
        candidates += [(run, condition, params)] * table.num_rows
    if not candidates:
        return [], []
    table = pa.concat_tables([t.replace_schema_metadata(None) for t in tables])
    success = table.column("success").to_numpy(zero_copy_only=False)
    state_ids = table.column("state_id").to_numpy()
    categories = table.column("failure_category").to_pylist()
    margin = np.concatenate(margin_parts)

    rows, wanted = [], {}
    for kind, picks in choose(success, margin, k).items():
        for rank, i in enumerate(picks, start=1):
            run = candidates[i][0]
            name = _condition_name(task_name, *run)
            rows.append(
                {
                    "task": task_name,
                    "kind": kind,
                    "rank": rank,
                    "method": run[0],
                    "seed": run[1],
                    "state_id": int(state_ids[i]),
                    "success": bool(success[i]),
                    "margin": float(margin[i]),
                    "margin_measure": task.margin.measure,
                    "failure_category": categories[i],
                    "recording_id": CLOSEST_CALLS_PREFIX
                    + episode_recording_id(name, int(state_ids[i])),
                }
            )
            wanted.setdefault(run, []).append(i)

    values = read_state_values(states, task)
    position = {int(s): i for i, s in enumerate(values["state_id"])}
    groups = []
    for run, picks in wanted.items():
        _, condition, params = candidates[picks[0]]
        run_bound = condition_task(condition, model, repo_root=repo_root)  # its policy file
        by_state = {int(state_ids[i]): i for i in picks}
        rows_of = [position[s] for s in sorted(by_state)]
        subset = {c: v[rows_of] for c, v in values.items()}
        episodes = []
        for batch in condition_batches(run_bound, condition, subset, nthread=1):
            again = task.margin.of(batch.outcome[task.margin.measure], params)
            for j, episode in enumerate(episode_records(run_bound.task, batch)):
                i = by_state[episode.state_id]
                if bool(success[i]) != episode.success or margin[i] != again[j]:
                    raise ValueError(
                        f"{evaluations[run]}: state {episode.state_id} re-simulated gave "
                        f"success {episode.success} and margin {float(again[j])!r}, the table "
                        f"{bool(success[i])} and {float(margin[i])!r}"
                    )
                episodes.append(episode)
        stamp_inputs = {
            "evaluation": evaluations[run],
            "parameters": parameters[run],
            **condition_policy_inputs(condition, repo_root=repo_root),
        }
        builder = EpisodeStores(
            recording_spec(run_bound, engine.episode_steps(run_bound, params), spec["rate_hz"]),
            condition=_condition_name(task_name, *run),
            stamp=make_stage_stamp(rule, dict(condition), stamp_inputs, repo_root=repo_root),
            share_meshes=True,  # a model's meshes once in the file, not in every episode
        )
        groups.append((builder, episodes))
    return rows, groups


def write_closest_calls(
    *,
    closest_slice: Mapping[str, Any],
    states: Mapping[str, Path],
    models: Mapping[str, Path],
    evaluations: Mapping[str, Path],
    parameters: Mapping[str, Path],
    output_rrd: Path,
    output_table: Path,
    rule: str = "closest_calls",
    repo_root: Path = REPO_ROOT,
) -> pa.Table:
    """`closest_slice`: `k` (episodes of each kind per task) and `tasks`: task ->
    `evaluate_slice` (as its evaluation jobs') and `rate_hz` (the recordings' logging rate);
    `states` and `models`: task -> its evaluation states and model file; `evaluations` and
    `parameters`: `<task>:<method>:<seed>` -> file."""
    tasks = closest_slice["tasks"]
    rows: list[dict[str, Any]] = []
    groups = []
    for task_name, spec in tasks.items():
        runs = {
            (key.split(":")[1], int(key.split(":")[2])): key
            for key in evaluations
            if key.split(":")[0] == task_name
        }
        task_rows, task_groups = _task_calls(
            task_name,
            spec,
            k=closest_slice["k"],
            states=Path(states[task_name]),
            model=Path(models[task_name]),
            evaluations={run: Path(evaluations[key]) for run, key in runs.items()},
            parameters={run: Path(parameters[key]) for run, key in runs.items()},
            rule=rule,
            repo_root=repo_root,
        )
        rows += task_rows
        groups += task_groups
    table = pa.Table.from_pylist(rows, schema=_schema()) if rows else _schema().empty_table()
    inputs: dict[str, Any] = {}
    for task_name, spec in tasks.items():
        inputs[f"states:{task_name}"] = Path(states[task_name])
        model = model_inputs(Path(models[task_name]))
        inputs |= {f"{task_name}:{key}": v for key, v in model.items()}
        task_files = task_inputs(spec["evaluate_slice"]["task"], repo_root=repo_root)
        inputs |= {f"{task_name}:{key}": v for key, v in task_files.items()}
    inputs |= {f"evaluation:{key}": Path(v) for key, v in evaluations.items()}
    inputs |= {f"parameters:{key}": Path(v) for key, v in parameters.items()}
    for key, path in parameters.items():  # the policy files the re-simulations ran
        policy = json.loads(Path(path).read_text(encoding="utf-8")).get("policy")
        if policy:
            inputs[f"policy:{key}"] = policy_inputs([Path(repo_root) / policy["path"]])["policy"]
    stamp = make_stage_stamp(rule, dict(closest_slice), inputs, repo_root=repo_root)
    n = write_episodes_rrd(
        output_rrd,
        groups,
        summary_id=CLOSEST_CALLS_SUMMARY,
        prefix=CLOSEST_CALLS_PREFIX,
        title=f"closest calls: {table.num_rows} episode(s) of {len(tasks)} task(s)",
        table=markdown_table(table),
        stamp=stamp,
    )
    provenance.write_parquet(table, Path(output_table), stamp)
    log.info("%s: %d episode(s) -> %s, %s", rule, n, output_rrd, output_table)
    return table


def _schema() -> pa.Schema:
    types = {
        "rank": pa.int64(),
        "seed": pa.int64(),
        "state_id": pa.int64(),
        "success": pa.bool_(),
        "margin": pa.float64(),
    }
    return pa.schema([(c, types.get(c, pa.string())) for c in COLUMNS])


def markdown_table(table: pa.Table) -> str:
    """The closest calls as a markdown table (the report's and the replay file's)."""
    lines = [
        "| task | kind | rank | method | seed | state | success | margin | failure |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    for r in table.to_pylist():
        lines.append(
            f"| {r['task']} | {r['kind']} | {r['rank']} | {r['method']} | {r['seed']} "
            f"| {r['state_id']} | {'yes' if r['success'] else 'no'} "
            f"| {r['margin']:.4g} ({r['margin_measure']}) | {r['failure_category'] or '-'} |"
        )
    return "\n".join(lines)
