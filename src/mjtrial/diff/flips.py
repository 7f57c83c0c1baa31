"""The flipped episodes: where two runs' recordings of one state first part, and one file that
holds both recordings of each, side by side, for the viewer."""

from __future__ import annotations

import os
import re
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

from mjtrial import provenance
from mjtrial.diff.source import Run
from mjtrial.files.layout import NOMINAL
from mjtrial.recording.divergence import DEFAULT_TOLERANCE, UNREADABLE, episode_divergence
from mjtrial.recording.failures import write_episode_copies_rrd
from mjtrial.recording.names import episode_file_name

# Flipped episodes whose trajectories are compared and copied into the diff's recording: by
# default (None) as many as fit `DEFAULT_RECORDING_BYTES` of recordings, so that a change that
# flips hundreds of episodes leaves a file a viewer opens (50 Fetch episodes made 67 MB).
DEFAULT_MAX_EPISODES: int | None = None
DEFAULT_RECORDING_BYTES = 10_000_000
# Flipped episodes a diff prints one by one, after their summary; the rest are in --json.
SHOWN_FLIPS = 10
# The runs' labels in the diff's recording.
SIDES = ("a", "b")


def episode_file(run: Run, group: str, state_id: int) -> Path | None:
    """The .rrd of one episode of a group (`condition` or `variant/condition`), in whichever
    shard of the run holds it; None when the run did not record it."""
    variant, _, condition = group.rpartition("/")
    base = f"variants/{variant}/rollouts" if variant and variant != NOMINAL else "rollouts"
    name = episode_file_name(condition, state_id)
    shard = re.compile(re.escape(f"{base}/{condition}/") + r"shard-\d+")
    for rel in run.outputs:
        if shard.fullmatch(rel):
            path = run.path(f"{rel}/{name}")
            if path.is_file():
                return path
    return None


def _trace(
    a: Run, b: Run, group: str, state_id: int, *, tolerance: float
) -> tuple[dict[str, Any], tuple[Path, Path] | None]:
    """One flipped episode's divergence (`episode_divergence`) and its two recordings, None
    when it has not both."""
    files = [episode_file(run, group, state_id) for run in (a, b)]
    divergence = episode_divergence(
        files,
        SIDES,
        condition=group.rpartition("/")[2],
        state_id=state_id,
        tolerance=tolerance,
    )
    unread = None in files or divergence.get("reason", "").startswith(UNREADABLE)
    return divergence, None if unread else (files[0], files[1])


def trace_flips(
    a: Run,
    b: Run,
    conditions: Mapping[str, Mapping[str, Any]],
    *,
    tolerance: float = DEFAULT_TOLERANCE,
    max_episodes: int | None = DEFAULT_MAX_EPISODES,
) -> list[tuple[str, int, Path, Path]]:
    """Add to each flipped episode of `conditions` (`found.compare_conditions`) its
    `divergence` where both runs recorded it: `first_divergence`, or why there is none. The
    first `max_episodes` so compared (None: until their recordings reach
    `DEFAULT_RECORDING_BYTES`) are returned as (group, state, file in a, file in b); the
    others say why they were not compared."""
    traced: list[tuple[str, int, Path, Path]] = []
    size = 0  # bytes of the traced episodes' recordings
    if max_episodes is None:
        past = (
            f"not compared (past the diff recording's {DEFAULT_RECORDING_BYTES / 1e6:.0f} MB; "
            "--max-episodes K compares K)"
        )
    else:
        past = f"not compared (past --max-episodes {max_episodes})"
    for group, record in conditions.items():
        for flip in record.get("flipped", []):
            sid = flip["state_id"]
            if (
                len(traced) >= max_episodes
                if max_episodes is not None
                else size >= DEFAULT_RECORDING_BYTES
            ):
                flip["divergence"] = {"reason": past}
                continue
            flip["divergence"], files = _trace(a, b, group, sid, tolerance=tolerance)
            if files is not None:
                traced.append((group, sid, *files))
                size += sum(f.stat().st_size for f in files)
    return traced


def write_diff_recording(
    path: Path, traced: Sequence[tuple[str, int, Path, Path]], *, labels: Sequence[str]
) -> int:
    """Both runs' recordings of each traced episode in one file at `path`, labelled `a` and
    `b` (the runs `labels`), after a table of them. Returns the number of episodes."""
    rows = ["| condition | state | a | b |", "|---|---|---|---|"]
    episodes = []
    for group, sid, file_a, file_b in traced:
        rows.append(f"| {group} | {sid} | {file_a.name} | {file_b.name} |")
        condition = group.rpartition("/")[2]
        for side, file in zip(SIDES, (file_a, file_b), strict=True):
            episodes.append((f"{side}-{group.replace('/', '-')}", file, condition, sid))
    names = [Path(label).name for label in labels]  # names only: no private paths in outputs
    legend = f"a: {names[0]}; b: {names[1]}"
    stamp = provenance.make_stamp(
        rule="diff",
        config_slice=dict(zip(SIDES, names, strict=True)),
        inputs={},
        repo_dir=os.getcwd(),
    )
    path.parent.mkdir(parents=True, exist_ok=True)
    write_episode_copies_rrd(
        path,
        episodes,
        summary_id="diff",
        title=f"diff: {len(traced)} flipped episode(s), both runs ({legend})",
        table=legend + "\n\n" + "\n".join(rows),
        stamp=stamp,
    )
    return len(episodes)
