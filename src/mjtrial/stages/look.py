"""A stopping rule's look after a shard: the e-value on the falsifier's pairs run so far, and
whether the experiment stops there (`mjtrial.stats.sequential`).

Each look is a Snakemake checkpoint (`workflow/rules/stopping.smk`): the workflow reads its
decision before it asks for the next shard, so a stopped experiment's later shards never run.
"""

from __future__ import annotations

import json
import logging
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow.parquet as pq

from mjtrial import REPO_ROOT, provenance
from mjtrial.files.layout import Layout, evaluation_shard_size, shard_ids
from mjtrial.stages.stamping import make_stage_stamp
from mjtrial.stats import sequential

log = logging.getLogger("mjtrial")


def _success(tables: Sequence[Path], *, what: str) -> np.ndarray:
    """The success column of consecutive shard tables, checked to hold states 0..n-1."""
    parts = [pq.read_table(p, columns=["state_id", "success"]) for p in tables]
    ids = np.concatenate([t.column("state_id").to_numpy() for t in parts]) if parts else []
    if not np.array_equal(ids, np.arange(len(ids))):
        raise ValueError(f"{what}: the shards' state ids are not 0..{len(ids) - 1} in order")
    return np.concatenate([t.column("success").to_numpy() for t in parts]).astype(bool)


def look_record(
    *,
    treatment_tables: Sequence[Path],
    baseline_tables: Sequence[Path],
    look_slice: Mapping[str, Any],
    shard: str,
) -> dict[str, Any]:
    """The look after `shard` from the shard tables up to it (`mjtrial verify` checks each
    look file against it): the stopping record of the pairs so far, and `stop`."""
    falsifier = look_slice["falsifier"]
    a = _success(treatment_tables, what=f"look {shard}: {falsifier['treatment']}")
    b = _success(baseline_tables, what=f"look {shard}: {falsifier['baseline']}")
    if a.size != b.size:
        raise ValueError(f"look {shard}: {a.size} treatment rows against {b.size} baseline rows")
    record = sequential.stopping_record(a, b, stopping=look_slice["stopping"])
    return {"shard": shard, "stop": record["stopped"], **record}


def run_look(
    *,
    treatment_tables: Sequence[Path],
    baseline_tables: Sequence[Path],
    look_slice: Mapping[str, Any],
    shard: str,
    output: Path,
    repo_root: Path = REPO_ROOT,
) -> dict[str, Any]:
    """Write the look after `shard` (stamped, rule `look:<shard>`)."""
    record = look_record(
        treatment_tables=treatment_tables,
        baseline_tables=baseline_tables,
        look_slice=look_slice,
        shard=shard,
    )
    stamp = make_stage_stamp(
        f"look:{shard}",
        dict(look_slice),
        {"treatment": list(treatment_tables), "baseline": list(baseline_tables)},
        repo_root=repo_root,
    )
    provenance.write_json(record, output, stamp)
    last = record["looks"][-1]
    log.info(
        "look %s: n = %d, %d/%d discordant pairs to the treatment, e-value %.3g (stop at %g): %s",
        shard,
        last["n"],
        last["treatment_only"],
        last["discordant"],
        last["e_value"],
        record["threshold"],
        "stop" if record["stop"] else "continue",
    )
    return record


def stops(look_file: Path | str) -> bool:
    """Whether a look file says the experiment stops after its shard."""
    return bool(json.loads(provenance.read_output_text(Path(look_file)))["stop"])


def shards_run(layout: Layout, config: Mapping[str, Any]) -> list[str]:
    """The evaluation's shards that ran, read from the look files on disk: every shard without
    a stopping rule, else each up to the first look that stopped (or the first missing look)."""
    shards = shard_ids(config["states"]["n"], evaluation_shard_size(config))
    if "stopping" not in config:
        return shards
    run = []
    for shard in shards:
        run.append(shard)
        look = layout.look(shard)
        if not look.is_file() or stops(look):
            break
    return run
