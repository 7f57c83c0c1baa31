"""The states stage: draw the evaluation (or development) states and write them."""

from __future__ import annotations

import logging
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow as pa

from mjtrial import REPO_ROOT, provenance
from mjtrial.stages.stamping import make_stage_stamp
from mjtrial.states import STATE_PARAMETERS, generate_initial_states

log = logging.getLogger("mjtrial")


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
    table = generate_initial_states(
        seed=states_slice["seed"], n=states_slice["n"], ranges=states_slice["ranges"]
    )
    tuning = generate_initial_states(
        seed=states_slice["development_seed"], n=states_slice["n"], ranges=states_slice["ranges"]
    )
    rows = {tuple(r) for r in np.column_stack([table.column(c) for c in STATE_PARAMETERS])}
    dev_rows = np.column_stack([tuning.column(c) for c in STATE_PARAMETERS])
    if any(tuple(r) in rows for r in dev_rows):
        raise ValueError(
            "states.development_seed: development and evaluation states overlap; "
            "expected disjoint seeds"
        )
    stamp = make_stage_stamp(
        "states:development" if development else "states",
        dict(states_slice),
        {},
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
