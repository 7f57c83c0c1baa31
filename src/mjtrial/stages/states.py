"""The states stage: draw the evaluation (or development) states and write them."""

from __future__ import annotations

import logging
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow as pa

from mjtrial import REPO_ROOT, provenance
from mjtrial.stages.stamping import make_stage_stamp, task_inputs
from mjtrial.states import generate_initial_states
from mjtrial.task import load_task

log = logging.getLogger("mjtrial")

# The stamp's rule of each set of states: what a job that must read one of them checks.
EVALUATION_RULE = "states"
DEVELOPMENT_RULE = "states:development"


def check_drawn_as(path: Path, *, development: bool, reader: str) -> dict[str, Any]:
    """The stamp of the states file `path`, which must be development (or evaluation) states;
    a one-line ValueError naming the file and `reader` (the job that may read only those)."""
    rule, what = (
        (DEVELOPMENT_RULE, "development") if development else (EVALUATION_RULE, "evaluation")
    )
    try:
        stamp = provenance.read_stamp(path)
    except (OSError, ValueError) as err:
        raise ValueError(f"{path}: no readable stamp ({err}); expected {what} states") from None
    if stamp.get("rule") != rule:
        raise ValueError(
            f"{path}: states drawn by {stamp.get('rule')!r}, not {what} states ({rule!r}); "
            f"{reader} reads {what} states only"
        )
    return stamp


def build_states(
    *,
    states_slice: Mapping[str, Any],
    output: Path,
    development: bool = False,
    repo_root: Path = REPO_ROOT,
) -> pa.Table:
    """Draw the evaluation states (or, with `development`, the tuning states) and write them.

    Both sets are drawn, to refuse a configuration whose development and evaluation states
    share a state: no reported number may come from a state used for tuning.
    """
    table, tuning = draw_states(states_slice, repo_root=repo_root)
    stamp = make_stage_stamp(
        DEVELOPMENT_RULE if development else EVALUATION_RULE,
        dict(states_slice),
        task_inputs(states_slice["task"], repo_root=repo_root),
        seeds={"states": states_slice["seed"], "development": states_slice["development_seed"]},
        repo_root=repo_root,
    )
    chosen, seed = (tuning, "development_seed") if development else (table, "seed")
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
    in its order; refused when the two sets share a state."""
    parameters = [
        p.name for p in load_task(states_slice["task"], repo_root=repo_root).state_parameters
    ]
    table, tuning = (
        generate_initial_states(
            seed=states_slice[key],
            n=states_slice["n"],
            ranges=states_slice["ranges"],
            parameters=parameters,
        )
        for key in ("seed", "development_seed")
    )
    rows = {tuple(r) for r in np.column_stack([table.column(c) for c in parameters])}
    dev_rows = np.column_stack([tuning.column(c) for c in parameters])
    if any(tuple(r) in rows for r in dev_rows):
        raise ValueError(
            "states.development_seed: development and evaluation states overlap; "
            "expected disjoint seeds"
        )
    return table, tuning
