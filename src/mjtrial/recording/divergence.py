"""Where two recordings of one episode part: the first logged time at which they differ.

`mjtrial diff` asks it of one state's episode in two runs; a sensitivity study of another
MuJoCo version asks it of the nominal model's episode and the variant's, in one run.
"""

from __future__ import annotations

import re
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from mjtrial.recording.read import read_episode

# Two trajectories part where a logged value differs by more than this (in its own units:
# metres, radians, the task's series). Recordings keep poses as float32, whose rounding of a
# coordinate under a few metres stays below 1e-6 m.
DEFAULT_TOLERANCE = 1e-6
UNREADABLE = "unreadable recording"


def first_divergence(
    a: Mapping[str, np.ndarray], b: Mapping[str, np.ndarray], *, tolerance: float
) -> dict[str, Any] | None:
    """The first logged time at which two recordings of an episode (`recording.read_episode`)
    differ by more than `tolerance` in any series or body pose they share, with each run's
    physics step there, the quantity and the difference; None when they never do.

    Only the times both logged are compared (a run with another timestep or logging rate logs
    at other times): the first step at which they part is known to the logging interval.
    """
    ta, tb = (np.round(np.asarray(r["time"]) * 1e9).astype(np.int64) for r in (a, b))
    common, ia, ib = np.intersect1d(ta, tb, return_indices=True)
    if common.size == 0:
        return {"time": None, "reason": "the runs logged no time in common"}
    worst = np.zeros(common.size)
    which = np.full(common.size, "", dtype=object)
    for key in sorted(set(a) & set(b) - {"time", "step"}):
        va, vb = np.asarray(a[key])[ia], np.asarray(b[key])[ib]
        if va.shape != vb.shape:
            continue
        gap = np.abs(va.astype(float) - vb)
        gap[np.isnan(va) & np.isnan(vb)] = 0.0  # both non-finite alike: not where they part
        gap = np.nan_to_num(gap, nan=np.inf).reshape(common.size, -1).max(axis=1)
        larger = gap > worst
        worst[larger], which[larger] = gap[larger], key
    parted = np.flatnonzero(worst > tolerance)
    if parted.size == 0:
        return None
    i = int(parted[0])
    return {
        "time": float(common[i] / 1e9),
        "step": [int(a["step"][ia[i]]), int(b["step"][ib[i]])],
        "quantity": str(which[i]),
        "difference": float(worst[i]),
    }


def episode_divergence(
    files: Sequence[Path | None],
    labels: Sequence[str],
    *,
    condition: str,
    state_id: int,
    tolerance: float = DEFAULT_TOLERANCE,
) -> dict[str, Any]:
    """`first_divergence` of an episode's two recordings (`files`, None where one side did not
    record it), or, under `reason`, why there is none: a side that did not record it (named by
    `labels`), an unreadable recording, or recordings that agree within `tolerance`."""
    missing = [label for label, f in zip(labels, files, strict=True) if f is None]
    if missing:
        return {"reason": f"not recorded in {' and '.join(missing)}"}
    try:
        series = [read_episode(f, condition=condition, state_id=state_id) for f in files]
    except (KeyError, ValueError) as err:  # a damaged recording: `mjtrial verify` says why
        return {"reason": f"{UNREADABLE}: {err}"}
    agree = {"reason": f"the recordings agree within {tolerance:g} at every time both logged"}
    return first_divergence(*series, tolerance=tolerance) or agree


def describe_divergence(d: Mapping[str, Any] | None) -> str:
    """A divergence (`first_divergence`, or why there is none) as a line of text."""
    if not d:
        return "-"
    if d.get("time") is None:
        return d.get("reason", "-")
    steps = d["step"]
    step = f"step {steps[0]}" if steps[0] == steps[1] else f"steps {steps[0]} | {steps[1]}"
    quantity = _unescaped(d["quantity"])
    return f"t = {d['time']:.4f} s, {step} ({quantity} by {d['difference']:.3g})"


def _unescaped(entity: str) -> str:
    """An entity path as a person reads it: Rerun's escapes of its parts removed
    (`rr.escape_entity_path_part`: `robot0\\:shoulder_lift_link` is `robot0:shoulder_lift_link`)."""
    return re.sub(r"\\(.)", r"\1", entity)
