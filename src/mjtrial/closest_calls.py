"""Closest calls: the successes that passed by the smallest margin, and the episodes a task
scores highest (the largest margins), so a reviewer can watch them.

A success test can be passed the wrong way (a cube thrown above the line still counts at the
instant it is judged), and a success rate says nothing about how many successes nearly failed.
The task's `Margin` gives each episode a signed distance from its success test's boundary;
these functions choose the episodes at both ends and check that the margins agree with the
success column (a margin that does not is a task bug, refused in one line).
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import numpy as np

from mjtrial.task import Task

CLOSEST = "closest success"  # a success of smallest margin
HIGHEST = "highest score"  # an episode of largest margin


def margins(task: Task, table: Any, params: Mapping[str, float], *, where: str) -> np.ndarray:
    """Each episode's margin, from its row of a rollout table (`table`: a pyarrow table), under
    the condition's protocol parameters `params` (defaults filled in).

    Raises:
      TaskError-like ValueError (one line) when the task has no margin, or a success has a
      negative margin or a failure a positive one.
    """
    if task.margin is None:
        raise ValueError(f"{task.source or task.name}: margin: expected a Margin(...) declaration")
    values = task.margin.of(
        table.column(task.margin.measure).to_numpy(zero_copy_only=False), params
    )
    success = np.asarray(table.column("success").to_numpy(zero_copy_only=False), dtype=bool)
    wrong = np.flatnonzero(
        np.isfinite(values) & ((success & (values < 0)) | (~success & (values > 0)))
    )
    if wrong.size:
        i = int(wrong[0])
        state = int(table.column("state_id")[i].as_py())
        raise ValueError(
            f"{task.source or task.name}: margin: state {state} of {where} has success "
            f"{bool(success[i])} but margin {values[i]:.6g} (expected > 0 for a success and <= 0 "
            f"for a failure); {len(wrong)} such episode(s)"
        )
    return values


def choose(success: np.ndarray, margin: np.ndarray, k: int) -> dict[str, np.ndarray]:
    """Row indices: `CLOSEST`, the `k` successes of smallest margin (smallest first), and
    `HIGHEST`, the `k` episodes of largest margin not already chosen (largest first). Rows
    without a finite margin (an unhealthy episode) are never chosen; ties keep row order."""
    success = np.asarray(success, dtype=bool)
    margin = np.asarray(margin, dtype=np.float64)
    finite = np.isfinite(margin)
    passed = np.flatnonzero(success & finite)
    closest = passed[np.argsort(margin[passed], kind="stable")][:k]
    rest = np.flatnonzero(finite)
    rest = rest[~np.isin(rest, closest)]
    highest = rest[np.argsort(-margin[rest], kind="stable")][:k]
    return {CLOSEST: closest, HIGHEST: highest}
