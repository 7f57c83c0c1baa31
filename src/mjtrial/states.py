"""Initial states: drawn once from a seeded generator and shared by every condition."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np
import pyarrow as pa

# Draw order is part of the experiment's definition: changing it changes every state.
STATE_PARAMETERS = ("dx", "dy", "yaw", "mass")
STATE_COLUMNS = ("state_id", *STATE_PARAMETERS)


@dataclass(frozen=True)
class InitialState:
    """One randomized initial state: cube offset (m), yaw (rad) and mass (kg)."""

    state_id: int
    dx: float
    dy: float
    yaw: float
    mass: float


def generate_initial_states(
    *,
    seed: int,
    n: int,
    ranges: Mapping[str, Sequence[float]],
    parameters: Sequence[str] = STATE_PARAMETERS,
) -> pa.Table:
    """N initial states: `default_rng(seed)`, then one `uniform` draw of n values per parameter.

    Args:
      seed: generator seed.
      n: number of states (>= 1).
      ranges: [low, high] of each parameter.
      parameters: the parameters in draw order (a task's `state_parameters`; default the
        gantry's dx (m), dy (m), yaw (rad), mass (kg)).

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


def states_from_table(table: pa.Table, *, source: str = "states table") -> list[InitialState]:
    """The table's rows as `InitialState` records, checking columns and values."""
    missing = [c for c in STATE_COLUMNS if c not in table.column_names]
    if missing:
        raise ValueError(f"{source}: missing column(s) {missing}; expected {list(STATE_COLUMNS)}")
    cols = {c: table.column(c).to_numpy(zero_copy_only=False) for c in STATE_COLUMNS}
    for c in STATE_PARAMETERS:
        bad = ~np.isfinite(cols[c].astype(float))
        if bad.any():
            first = int(cols["state_id"][np.argmax(bad)])
            raise ValueError(
                f"{source}: column {c!r} has non-finite values (first at state {first})"
            )
    return [
        InitialState(int(i), float(dx), float(dy), float(yaw), float(mass))
        for i, dx, dy, yaw, mass in zip(*(cols[c] for c in STATE_COLUMNS), strict=True)
    ]
