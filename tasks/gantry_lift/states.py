"""The gantry's initial states as records (`InitialState`), read from a states table: what
the reference stepper (`simulate.py`) and the tests take."""

from __future__ import annotations

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
