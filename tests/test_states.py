"""Initial states are the documented draws of a seeded generator, exactly."""

from __future__ import annotations

import numpy as np
import pyarrow as pa
import pytest

from mjtrial.states import generate_initial_states, states_from_table

RANGES = {"dx": [-0.018, 0.018], "dy": [-0.012, 0.012], "yaw": [-0.6, 0.6], "mass": [0.05, 0.6]}


def test_draws_are_default_rng_uniform_in_order():
    table = generate_initial_states(seed=2026, n=50, ranges=RANGES)
    rng = np.random.default_rng(2026)
    for name in ("dx", "dy", "yaw", "mass"):
        low, high = RANGES[name]
        np.testing.assert_array_equal(table.column(name).to_numpy(), rng.uniform(low, high, 50))
    np.testing.assert_array_equal(table.column("state_id").to_numpy(), np.arange(50))


def test_evaluation_mass_bands_hold_47_65_88():
    mass = generate_initial_states(seed=2026, n=200, ranges=RANGES).column("mass").to_numpy()
    counts = [
        int(((mass >= 0.05) & (mass < 0.23)).sum()),
        int(((mass >= 0.23) & (mass < 0.42)).sum()),
        int(((mass >= 0.42) & (mass <= 0.6)).sum()),
    ]
    assert counts == [47, 65, 88]


def test_rejects_bad_arguments():
    with pytest.raises(ValueError, match="n: expected at least 1"):
        generate_initial_states(seed=1, n=0, ranges=RANGES)
    with pytest.raises(ValueError, match=r"ranges\.yaw: expected low < high"):
        generate_initial_states(seed=1, n=3, ranges={**RANGES, "yaw": [0.6, -0.6]})


def test_states_from_table_checks_columns_and_values():
    table = generate_initial_states(seed=3, n=4, ranges=RANGES)
    states = states_from_table(table)
    assert [s.state_id for s in states] == [0, 1, 2, 3]
    assert states[2].mass == table.column("mass")[2].as_py()
    with pytest.raises(ValueError, match=r"states\.parquet: missing column\(s\) \['yaw'\]"):
        states_from_table(table.drop_columns(["yaw"]), source="states.parquet")
    mass = table.column("mass").to_numpy().copy()
    mass[1] = np.nan
    bad = table.set_column(4, "mass", pa.array(mass))
    with pytest.raises(ValueError, match="'mass' has non-finite values"):
        states_from_table(bad)
