"""Initial states are the documented draws of a seeded generator, exactly."""

from __future__ import annotations

import numpy as np
import pyarrow as pa
import pytest
from gantry_lift.states import STATE_PARAMETERS, states_from_table

from mjtrial.design.states import generate_initial_states

RANGES = {"dx": [-0.018, 0.018], "dy": [-0.012, 0.012], "yaw": [-0.6, 0.6], "mass": [0.05, 0.6]}


def test_draws_are_default_rng_uniform_in_order():
    table = generate_initial_states(seed=2026, n=50, ranges=RANGES, parameters=STATE_PARAMETERS)
    rng = np.random.default_rng(2026)
    for name in ("dx", "dy", "yaw", "mass"):
        low, high = RANGES[name]
        np.testing.assert_array_equal(table.column(name).to_numpy(), rng.uniform(low, high, 50))
    np.testing.assert_array_equal(table.column("state_id").to_numpy(), np.arange(50))


def test_evaluation_mass_bands_hold_47_65_88():
    mass = (
        generate_initial_states(seed=2026, n=200, ranges=RANGES, parameters=STATE_PARAMETERS)
        .column("mass")
        .to_numpy()
    )
    counts = [
        int(((mass >= 0.05) & (mass < 0.23)).sum()),
        int(((mass >= 0.23) & (mass < 0.42)).sum()),
        int(((mass >= 0.42) & (mass <= 0.6)).sum()),
    ]
    assert counts == [47, 65, 88]


def test_rejects_bad_arguments():
    with pytest.raises(ValueError, match="n: expected at least 1"):
        generate_initial_states(seed=1, n=0, ranges=RANGES, parameters=STATE_PARAMETERS)
    with pytest.raises(ValueError, match=r"ranges\.yaw: expected low < high"):
        generate_initial_states(
            seed=1, n=3, ranges={**RANGES, "yaw": [0.6, -0.6]}, parameters=STATE_PARAMETERS
        )


def test_states_from_table_checks_columns_and_values():
    table = generate_initial_states(seed=3, n=4, ranges=RANGES, parameters=STATE_PARAMETERS)
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


def test_the_task_declares_the_parameters_and_their_draw_order():
    """The states stage draws the task's state parameters, in the order it declares them."""
    from conftest import REPO_ROOT

    from mjtrial.stages.states import draw_states

    ranges = {
        "push_time": [0.5, 1.0],
        "pole_angle": [-0.1, 0.1],
        "pole_rate": [-0.5, 0.5],
        "pole_mass": [0.05, 0.3],
        "push_force": [-6.0, 6.0],
    }
    states_slice = {
        "seed": 7,
        "development_seed": 8,
        "n": 30,
        "ranges": ranges,
        "task": "tasks/cartpole_latency/task.py",
    }
    table, tuning = draw_states(states_slice, repo_root=REPO_ROOT)
    order = ["pole_angle", "pole_rate", "pole_mass", "push_force", "push_time"]
    assert table.column_names == ["state_id", *order]
    for drawn, seed in ((table, 7), (tuning, 8)):
        rng = np.random.default_rng(seed)
        for name in order:
            expected = rng.uniform(*ranges[name], 30)
            np.testing.assert_array_equal(drawn.column(name).to_numpy(), expected)

    gantry = {"seed": 2026, "development_seed": 1, "n": 50, "ranges": RANGES}
    table, _ = draw_states(gantry | {"task": "tasks/gantry_lift/task.py"}, repo_root=REPO_ROOT)
    assert table.equals(
        generate_initial_states(seed=2026, n=50, ranges=RANGES, parameters=STATE_PARAMETERS)
    )


def test_a_normal_and_a_truncated_normal_are_one_draw_each_in_order():
    """Against a generator driven here call by call: uniform parameters keep the values a
    config without distributions draws, bit for bit; a normal is numpy's `normal`; a truncated
    normal is one `uniform` draw through scipy's inverse CDF."""
    from scipy import stats

    distributions = {
        "dy": {"kind": "normal", "mean": 0.0, "std": 0.005},
        "yaw": {"kind": "truncated_normal", "mean": 0.2, "std": 0.4},
    }
    table = generate_initial_states(
        seed=2026, n=400, ranges=RANGES, parameters=STATE_PARAMETERS, distributions=distributions
    )
    rng = np.random.default_rng(2026)
    expected = {
        "dx": rng.uniform(-0.018, 0.018, 400),
        "dy": rng.normal(0.0, 0.005, 400),
        "yaw": stats.truncnorm.ppf(rng.uniform(size=400), -2.0, 1.0, loc=0.2, scale=0.4),
        "mass": rng.uniform(0.05, 0.6, 400),
    }
    for name, values in expected.items():
        np.testing.assert_array_equal(table.column(name).to_numpy(), values)
    plain = generate_initial_states(seed=2026, n=400, ranges=RANGES, parameters=STATE_PARAMETERS)
    np.testing.assert_array_equal(table.column("dx").to_numpy(), plain.column("dx").to_numpy())
    # the truncated normal stays in its range and is the distribution it says (a KS test)
    yaw = table.column("yaw").to_numpy()
    assert yaw.min() >= -0.6 and yaw.max() <= 0.6
    assert stats.kstest(yaw, stats.truncnorm(-2.0, 1.0, loc=0.2, scale=0.4).cdf).pvalue > 0.05
    assert stats.kstest(table.column("dy").to_numpy(), stats.norm(0, 0.005).cdf).pvalue > 0.05


def test_valid_states_are_redrawn_from_the_same_distributions():
    from mjtrial.design.states import draw_valid_states

    distributions = {"dx": {"kind": "normal", "mean": 0.0, "std": 0.01}}
    table, rejected = draw_valid_states(
        seed=7,
        n=50,
        ranges=RANGES,
        parameters=STATE_PARAMETERS,
        valid=lambda v: v["dx"] > 0,
        distributions=distributions,
    )
    first = (
        generate_initial_states(
            seed=7, n=50, ranges=RANGES, parameters=STATE_PARAMETERS, distributions=distributions
        )
        .column("dx")
        .to_numpy()
    )
    kept = first[first > 0]
    np.testing.assert_array_equal(table.column("dx").to_numpy()[: len(kept)], kept)
    assert rejected > 0


def test_the_states_stage_draws_the_configs_distributions():
    from conftest import REPO_ROOT

    from mjtrial.stages.states import draw_states

    distributions = {"yaw": {"kind": "truncated_normal", "mean": 0.0, "std": 0.3}}
    states_slice = {
        "seed": 5,
        "development_seed": 6,
        "n": 30,
        "ranges": RANGES,
        "distributions": distributions,
        "task": "tasks/gantry_lift/task.py",
    }
    table, _ = draw_states(states_slice, repo_root=REPO_ROOT)
    expected = generate_initial_states(
        seed=5, n=30, ranges=RANGES, parameters=STATE_PARAMETERS, distributions=distributions
    )
    assert table.equals(expected)
    assert not table.equals(
        generate_initial_states(seed=5, n=30, ranges=RANGES, parameters=STATE_PARAMETERS)
    )
