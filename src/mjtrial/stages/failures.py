"""The failures stage: every failed episode's recording, gathered into one `failures.rrd`."""

from __future__ import annotations

import logging
from collections.abc import Sequence
from pathlib import Path

import pyarrow.parquet as pq

from mjtrial import REPO_ROOT, recording
from mjtrial.stages.stamping import make_stage_stamp

log = logging.getLogger("mjtrial")


def gather_failures(
    *,
    recordings: Sequence[Path],
    tables: Sequence[Path],
    output: Path,
    repo_root: Path = REPO_ROOT,
) -> int:
    """Gather every failed episode of every condition into one `failures.rrd`.

    `recordings` are the conditions' folders (`rollouts/<condition>/`), `tables` their rollout
    tables, in the same order: the tables say which episodes failed, so only their files are
    opened (at 100 000 states, opening every file would take minutes); a recording that does
    not say it failed is an error (`recording.write_failures_rrd`'s `only_failures`).
    """
    if len(recordings) != len(tables):
        raise ValueError(f"{len(recordings)} recording folders but {len(tables)} tables")
    files = []
    for folder, table in zip(map(Path, recordings), map(Path, tables), strict=True):
        rows = pq.read_table(table, columns=["state_id", "success"]).to_pylist()
        files += [
            folder / recording.episode_file_name(folder.name, row["state_id"])
            for row in rows
            if not row["success"]
        ]
    inputs = {p.stem: p for p in recordings} | {f"{p.stem}_table": p for p in tables}
    stamp = make_stage_stamp("failures", {}, inputs, repo_root=repo_root)
    count = recording.write_failures_rrd(output, files, stamp=stamp, only_failures=True)
    log.info("failures: %d failed episodes -> %s", count, output)
    return count
