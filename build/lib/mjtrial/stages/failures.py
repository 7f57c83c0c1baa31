"""The failures stage: the failed episodes' recordings in one `failures.rrd`, bounded, and a
table of every failure beside it.

At 100,000 states the failures can be tens of thousands; the viewer opens a file whole, so
`failures.rrd` holds at most `failures_max` of them, chosen deterministically and spread over
conditions and failure categories, and `failures.parquet` lists every one (each replayable
with `mjtrial replay`).
"""

from __future__ import annotations

import itertools
import logging
from collections.abc import Mapping, Sequence
from pathlib import Path

import pyarrow as pa
import pyarrow.parquet as pq

from mjtrial import REPO_ROOT, provenance, recording
from mjtrial.stages.stamping import make_stage_stamp

log = logging.getLogger("mjtrial")

FAILURES_SCHEMA = pa.schema(
    [
        ("condition", pa.string()),
        ("state_id", pa.int64()),
        ("failure_category", pa.string()),
        ("in_failures_rrd", pa.bool_()),
    ]
)


def choose_failures(
    failures: Sequence[tuple[str, int, str]], *, at_most: int
) -> set[tuple[str, int]]:
    """Which failures go into `failures.rrd`: round robin over the (condition, category) groups,
    in name order, each group's lowest state ids first, until `at_most` are chosen.

    Args:
      failures: (condition, state_id, failure category) of every failed episode.
    """
    groups: dict[tuple[str, str], list[int]] = {}
    for condition, state_id, category in failures:
        groups.setdefault((condition, str(category)), []).append(int(state_id))
    queues = [iter(sorted(ids)) for _, ids in sorted(groups.items())]
    chosen: list[tuple[str, int]] = []
    names = [key[0] for key, _ in sorted(groups.items())]
    for _ in itertools.count():
        took = False
        for condition, queue in zip(names, queues, strict=True):
            state_id = next(queue, None)
            if state_id is not None and len(chosen) < at_most:
                chosen.append((condition, state_id))
                took = True
        if not took or len(chosen) >= at_most:
            break
    return set(chosen)


def gather_failures(
    *,
    tables: Mapping[str, Path],
    failures_max: int,
    shard_folders: Mapping[str, Sequence[Path]],
    output: Path,
    output_table: Path,
    repo_root: Path = REPO_ROOT,
) -> int:
    """Write `failures.rrd` (at most `failures_max` failed episodes) and `failures.parquet`.

    Args:
      tables: condition -> its rollout table; the tables say which episodes failed, so only
        the chosen episodes' files are opened.
      shard_folders: condition -> its shards' folders as the layout names them: where the
        recordings are read, and the stamp's inputs (never a glob, which would pick up an
        earlier configuration's leftovers).

    A recording that does not say it failed is an error (`write_failures_rrd`'s
    `only_failures`).
    """
    failures: list[tuple[str, int, str]] = []
    for condition, table in tables.items():
        rows = pq.read_table(table, columns=["state_id", "success", "failure_category"])
        for row in rows.to_pylist():
            if not row["success"]:
                failures.append((condition, row["state_id"], row["failure_category"]))
    chosen = choose_failures(failures, at_most=failures_max)
    files = [
        recording.find_episode_file(shard_folders[c], condition=c, state_id=s)
        for c, s, _ in failures
        if (c, s) in chosen
    ]
    inputs = {f"{c}_table": p for c, p in tables.items()}
    inputs |= {c: list(shard_folders[c]) for c in tables}
    stamp = make_stage_stamp(
        "failures", {"failures_max": failures_max}, inputs, repo_root=repo_root
    )
    count = recording.write_failures_rrd(output, files, stamp=stamp, only_failures=True)
    listed = pa.table(
        {
            "condition": [c for c, _, _ in failures],
            "state_id": [s for _, s, _ in failures],
            "failure_category": [k for _, _, k in failures],
            "in_failures_rrd": [(c, s) in chosen for c, s, _ in failures],
        },
        schema=FAILURES_SCHEMA,
    )
    provenance.write_parquet(listed, output_table, stamp)
    log.info(
        "failures: %d failed episodes, %d of them in %s; all listed in %s",
        len(failures),
        count,
        output,
        output_table,
    )
    return count
