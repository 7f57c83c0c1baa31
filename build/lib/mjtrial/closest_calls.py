"""Closest calls: the successes that passed by the smallest margin, and the episodes a task
scores highest (the largest margins), so a reviewer can watch them.

A success test can be passed the wrong way (an object thrown above the line still counts at
the instant it is judged), and a success rate says nothing about how many successes nearly failed.
The task's `Margin` gives each episode a signed distance from its success test's boundary;
these functions choose the episodes at both ends and check that the margins agree with the
success column (a margin that does not is a task bug, refused in one line).
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np


@dataclass(frozen=True)
class Margin:
    """How far an episode was from the success test's boundary, from one of the table's
    measures: `measure - boundary` (`above`: success is the measure above the boundary) or
    `boundary - measure`; positive for a success, zero or below for a failure.

    The closest calls are the successes of smallest margin, which a small change would have
    failed, and the episodes of largest margin, the task's highest scores, where a success test
    that can be gamed (an object thrown above the line) shows.
    `boundary` is a number, or a function of the condition's protocol parameters.
    """

    measure: str
    boundary: float | Callable[[Mapping[str, float]], float]
    above: bool = True

    def of(self, values: np.ndarray, params: Mapping[str, float]) -> np.ndarray:
        """The margins of the measure's `values` under a condition's parameters."""
        boundary = self.boundary(params) if callable(self.boundary) else self.boundary
        values = np.asarray(values, dtype=np.float64)
        return values - float(boundary) if self.above else float(boundary) - values


CLOSEST = "closest success"  # a success of smallest margin
HIGHEST = "highest score"  # an episode of largest margin


def margins(
    margin: Margin, table: Any, params: Mapping[str, float], *, source: str, where: str
) -> np.ndarray:
    """Each episode's margin, from its row of a rollout table (`table`: a pyarrow table), under
    the condition's protocol parameters `params` (defaults filled in).

    Raises:
      ValueError, one line naming `source` (the task's file) and `where` (the table), when a
      success has a negative margin or a failure a positive one.
    """
    values = margin.of(table.column(margin.measure).to_numpy(zero_copy_only=False), params)
    success = np.asarray(table.column("success").to_numpy(zero_copy_only=False), dtype=bool)
    wrong = np.flatnonzero(
        np.isfinite(values) & ((success & (values < 0)) | (~success & (values > 0)))
    )
    if wrong.size:
        i = int(wrong[0])
        state = int(table.column("state_id")[i].as_py())
        raise ValueError(
            f"{source}: margin: state {state} of {where} has success "
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
