"""`mjtrial diff A B`: why a number changed between two runs.

Each run is a results folder or an archive of one (`mjtrial crate --zip`), read as it is on
disk, never through the checkout the diff runs in. The diff says what differs in how they were
made (`made`), in what they found (`found`), which episodes flipped and where their
trajectories part (`flips`), and the exit code of a regression gate (`gate`).
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any

from mjtrial.diff.flips import (
    DEFAULT_MAX_EPISODES,
    DEFAULT_TOLERANCE,
    trace_flips,
    write_diff_recording,
)
from mjtrial.diff.found import compare_conditions, compare_effects, compare_outputs
from mjtrial.diff.gate import DEFAULT_LEVEL, FAIL_ON, failures, render
from mjtrial.diff.made import how_made
from mjtrial.diff.registration import compare_registrations
from mjtrial.diff.source import RunError, open_run

__all__ = [
    "DEFAULT_LEVEL",
    "DEFAULT_MAX_EPISODES",
    "DEFAULT_TOLERANCE",
    "FAIL_ON",
    "RunError",
    "diff_runs",
    "failures",
    "render",
]


def _inside(path: Path, folder: Path) -> bool:
    """Whether `path` lies in `folder`, as written or through a symlink on either side."""
    return Path(os.path.abspath(path)).is_relative_to(os.path.abspath(folder)) or Path(
        os.path.realpath(path)
    ).is_relative_to(os.path.realpath(folder))


def diff_runs(
    a: str | os.PathLike[str],
    b: str | os.PathLike[str],
    *,
    recording: Path | None = None,
    tolerance: float = DEFAULT_TOLERANCE,
    max_episodes: int | None = DEFAULT_MAX_EPISODES,
    level: float = DEFAULT_LEVEL,
) -> dict[str, Any]:
    """The diff of runs `a` and `b`, a JSON-able dict: `runs`, `registration`
    (`registration.compare_registrations`), `made` (`made.how_made`),
    `outputs` (`found.compare_outputs`), `conditions` (`found.compare_conditions`, each
    flipped episode with its `divergence`), `effects` (`found.compare_effects`), the
    `tolerance`, the McNemar `level`, and `recording`: the file `recording` names, written
    when an episode flipped and both runs recorded it (both recordings side by side), else
    None.

    Raises:
      RunError: `a` or `b` is not a run the diff can read, or `recording` lies in one.
      ValueError: `level` not in (0, 1), `tolerance` below 0.
    """
    if not 0 < level < 1:
        raise ValueError(f"level {level!r}: expected in (0, 1)")
    if not tolerance >= 0:
        raise ValueError(f"tolerance {tolerance!r}: expected >= 0")
    runs = [open_run(a)]
    try:
        runs.append(open_run(b))
        for run in runs:
            if recording is not None and run.archive is None and _inside(recording, run.root):
                raise RunError(
                    f"{recording}: inside the run {run.label}; a diff never writes into a run "
                    "(verify would take the file for one of the run's): give --out outside it"
                )
        conditions = compare_conditions(*runs)
        traced = trace_flips(*runs, conditions, tolerance=tolerance, max_episodes=max_episodes)
        written = None
        if recording is not None and traced:
            write_diff_recording(recording, traced, labels=[r.label for r in runs])
            written = str(recording)
        return {
            "runs": {"a": runs[0].label, "b": runs[1].label},
            "registration": compare_registrations(*runs),
            "made": how_made(*runs),
            "outputs": compare_outputs(*runs),
            "conditions": conditions,
            "effects": compare_effects(*runs),
            "tolerance": tolerance,
            "level": level,
            "recording": written,
        }
    finally:
        for run in runs:
            run.close()
