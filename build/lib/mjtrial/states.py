"""Initial states: drawn once from a seeded generator and shared by every condition."""

from __future__ import annotations

from collections.abc import Mapping, Sequence

import numpy as np
import pyarrow as pa


def generate_initial_states(
    *,
    seed: int,
    n: int,
    ranges: Mapping[str, Sequence[float]],
    parameters: Sequence[str],
) -> pa.Table:
    """N initial states: `default_rng(seed)`, then one `uniform` draw of n values per parameter.

    Args:
      seed: generator seed.
      n: number of states (>= 1).
      ranges: [low, high] of each parameter.
      parameters: the parameters in draw order (a task's `state_parameters`, in the order it
        declares them: the order is part of the experiment's definition, changing it changes
        every state).

    Returns:
      Table with columns state_id (0..n-1) and the parameters; n rows.
    """
    if n < 1:
        raise ValueError(f"n: expected at least 1 state, got {n}")
    rng = np.random.default_rng(seed)
    columns: dict[str, np.ndarray] = {"state_id": np.arange(n, dtype=np.int64)}
    for name in parameters:
        if name not in ranges:
            raise ValueError(f"ranges.{name}: missing; expected [low, high]")
        low, high = ranges[name]
        if not low < high:
            raise ValueError(f"ranges.{name}: expected low < high, got [{low}, {high}]")
        columns[name] = rng.uniform(low, high, n)
    return pa.table(columns)
