"""The states stage: draw the evaluation (or development) states and write them."""

from __future__ import annotations

import logging
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq

from mjtrial import REPO_ROOT, provenance
from mjtrial.design.states import (
    ConstraintError,
    NotAStateFunctionError,
    draw_valid_states,
    generate_initial_states,
)
from mjtrial.files.layout import Layout
from mjtrial.stages.stamping import make_stage_stamp, task_inputs
from mjtrial.task import NotAFunctionError, TaskError, call, load_task

log = logging.getLogger("mjtrial")

# The stamp's rule of each set of states: what a job that must read one of them checks.
EVALUATION_RULE = "states"
DEVELOPMENT_RULE = "states:development"


def states_rule(*, development: bool, task: str | None = None) -> str:
    """The stamp's rule of a set of states: an experiment's `states` or `states:development`;
    a benchmark task's `states:evaluation:<task>` or `states:development:<task>`, so that each
    task's states job is a job of its own in the crate and verify can tell whose they are."""
    if task is None:
        return DEVELOPMENT_RULE if development else EVALUATION_RULE
    return f"states:{'development' if development else 'evaluation'}:{task}"


def drawn_as(rule: object) -> str | None:
    """The kind of states a stamp's rule (`states_rule`) drew: "development" or "evaluation";
    None for a rule that draws no states."""
    parts = rule.split(":") if isinstance(rule, str) else []
    if not parts or parts[0] != "states":
        return None
    if len(parts) == 1:
        return "evaluation"
    return parts[1] if parts[1] in ("development", "evaluation") else None


def check_drawn_as(path: Path, *, development: bool, reader: str) -> dict[str, Any]:
    """The stamp of the states file `path`, which must be development (or evaluation) states;
    a one-line ValueError naming the file and `reader` (the job that may read only those)."""
    what = "development" if development else "evaluation"
    try:
        stamp = provenance.read_stamp(path)
    except (OSError, ValueError) as err:
        raise ValueError(f"{path}: no readable stamp ({err}); expected {what} states") from None
    if drawn_as(stamp.get("rule")) != what:
        raise ValueError(
            f"{path}: states drawn by {stamp.get('rule')!r}, not {what} states; "
            f"{reader} reads {what} states only"
        )
    return stamp


def check_evaluation_table(path: Path, *, reader: str) -> None:
    """Refuse a rollout table the evaluation must not read: one whose stamp is not a gather's
    (the pilot's are `pilot_gather`); a one-line ValueError naming the file and `reader`."""
    try:
        rule = provenance.read_stamp(path).get("rule")
    except (OSError, ValueError) as err:
        raise ValueError(f"{path}: no readable stamp ({err}); expected a rollout table") from None
    if not (isinstance(rule, str) and rule.startswith("gather:")):
        raise ValueError(
            f"{path}: written by {rule!r}, not the evaluation's gather; {reader} reads the "
            "evaluation's rollout tables only"
        )


def build_states(
    *,
    states_slice: Mapping[str, Any],
    output: Path,
    development: bool = False,
    rule: str | None = None,
    repo_root: Path = REPO_ROOT,
) -> pa.Table:
    """Draw the evaluation states (or, with `development`, the tuning states) and write them.

    Both sets are drawn, to refuse a configuration whose development and evaluation states
    share a state: no reported number may come from a state used for tuning.
    """
    table, tuning, redrawn = draw_counted_states(states_slice, repo_root=repo_root)
    stamp = make_stage_stamp(
        rule or states_rule(development=development),
        dict(states_slice),
        task_inputs(states_slice["task"], repo_root=repo_root),
        seeds={"states": states_slice["seed"], "development": states_slice["development_seed"]},
        repo_root=repo_root,
        # a task's `valid_state`: the drawn states it rejected, per set (`draw_valid_states`)
        extra=None if redrawn is None else {REDRAWN: redrawn},
    )
    chosen, seed = (tuning, "development_seed") if development else (table, "seed")
    if not development:
        check_not_piloted(table, development=Layout(Path(output).parent).development)
    provenance.write_parquet(chosen, output, stamp)
    log.info(
        "states: %d %s states (seed %d) -> %s",
        chosen.num_rows,
        "development" if development else "evaluation",
        states_slice[seed],
        output,
    )
    return chosen


def draw_states(states_slice: Mapping[str, Any], *, repo_root: Path) -> tuple[pa.Table, pa.Table]:
    """The evaluation and development states of a states slice, the task's parameters drawn
    in its order (`draw_counted_states`); refused when the two sets share a state."""
    table, tuning, _ = draw_counted_states(states_slice, repo_root=repo_root)
    return table, tuning


# The states stamp's record of the states a task's `valid_state` rejected: set -> count.
REDRAWN = "states_redrawn"


def draw_counted_states(
    states_slice: Mapping[str, Any], *, repo_root: Path
) -> tuple[pa.Table, pa.Table, dict[str, int] | None]:
    """`draw_states`' two sets, and for a task with a `valid_state` the number of drawn states
    it rejected in each ({"evaluation": k, "development": k}; None without one). The task's
    constraint is applied to both sets by the same rule (`mjtrial.design.states.draw_valid_states`);
    without one the states are `generate_initial_states`' draw."""
    task = load_task(states_slice["task"], repo_root=repo_root)
    parameters = [p.name for p in task.state_parameters]
    drawn = {}
    for key, kind in (("seed", "evaluation"), ("development_seed", "development")):
        given = dict(
            seed=states_slice[key],
            n=states_slice["n"],
            parameters=parameters,
            distributions=states_slice.get("distributions"),
        )
        if task.valid_state is None:
            drawn[kind] = (generate_initial_states(ranges=states_slice["ranges"], **given), 0)
            continue
        try:
            drawn[kind] = draw_valid_states(
                ranges=states_slice["ranges"],
                valid=lambda values: call(task, "valid_state", task.valid_state, values),
                **given,
            )
        except ConstraintError as err:
            kind = NotAFunctionError if isinstance(err, NotAStateFunctionError) else TaskError
            raise kind(f"{task.source or task.name}: valid_state: {err}") from None
    (table, evaluation), (tuning, development) = drawn["evaluation"], drawn["development"]
    redrawn = None
    if task.valid_state is not None:
        redrawn = {"evaluation": evaluation, "development": development}
    rows = {tuple(r) for r in np.column_stack([table.column(c) for c in parameters])}
    dev_rows = np.column_stack([tuning.column(c) for c in parameters])
    if any(tuple(r) in rows for r in dev_rows):
        raise ValueError(
            "states.development_seed: development and evaluation states overlap; "
            "expected disjoint seeds"
        )
    return table, tuning, redrawn


def piloted_states(development: Layout) -> pa.Table | None:
    """The development states a pilot of this experiment ran (`snakemake -c2 pilot`): the rows
    of `development`'s states file whose ids a pilot shard under it holds, that shard made
    from that very file (its stamp's sha256); None when no pilot ran on it."""
    states_file = development.states
    shards = sorted(development.rollouts_dir().rglob("shard-*.parquet"))
    if not states_file.is_file() or not shards:
        return None
    sha = provenance.file_sha256(states_file)
    ids: set[int] = set()
    for shard in shards:
        try:
            stamp = provenance.read_stamp(shard)
            source = stamp["inputs"]["states"]["sha256"]
        except (OSError, ValueError, KeyError, TypeError):
            continue
        if str(stamp.get("rule", "")).startswith("pilot:") and source == sha:
            ids.update(int(i) for i in pq.read_table(shard, columns=["state_id"])[0])
    if not ids:
        return None
    table = pq.read_table(states_file)
    keep = np.isin(table.column("state_id").to_numpy(), sorted(ids))
    return table.filter(pa.array(keep))


def piloted_overlap(table: pa.Table, *, development: Layout) -> str | None:
    """Why evaluation states `table` are refused: a one-line reason when any of them is a
    state a pilot of this experiment tuned on (`piloted_states`), else None. A pilot's states
    stay development states for the experiment, whatever its seeds say since."""
    piloted = piloted_states(development)
    if piloted is None:
        return None
    parameters = [c for c in table.column_names if c != "state_id"]
    if not set(parameters) <= set(piloted.column_names):
        return None  # another task's states: not this experiment's pilot
    tuned = {tuple(r) for r in np.column_stack([piloted.column(c) for c in parameters])}
    rows = np.column_stack([table.column(c) for c in parameters])
    shared = sum(tuple(r) in tuned for r in rows)
    if not shared:
        return None
    seed = (provenance.read_stamp(development.states).get("seeds") or {}).get("development")
    return (
        f"states.seed: {shared} of the {table.num_rows} evaluation states are states the pilot "
        f"tuned on ({development.states}, development_seed {seed}); a pilot's states stay "
        "development states for this experiment: expected a states.seed drawing other states"
    )


def check_not_piloted(table: pa.Table, *, development: Layout) -> None:
    """Refuse evaluation states a pilot of this experiment ran (`piloted_overlap`): a one-line
    ValueError naming the key, the pilot's states file and what is expected."""
    reason = piloted_overlap(table, development=development)
    if reason is not None:
        raise ValueError(reason)
