"""The closest calls' choice (against a naive sort), a task's `Margin` and its checks: the
margin's sign is the success test's, and a task whose margin disagrees is refused in one line."""

from __future__ import annotations

import shutil

import numpy as np
import pyarrow as pa
import pytest
from conftest import REPO_ROOT

from mjtrial.closest_calls import CLOSEST, HIGHEST, choose, margins
from mjtrial.sim.engine import iter_batches
from mjtrial.task import BoundTask, Margin, TaskError, load_task

CARTPOLE_TASK = "tasks/cartpole_latency/task.py"


def naive_choice(success, margin, k):
    """The same choice by a plain Python sort over (margin, row) pairs."""
    rows = [(m, i) for i, m in enumerate(margin) if m == m]  # NaN never chosen
    closest = [i for m, i in sorted((m, i) for m, i in rows if success[i])][:k]
    # largest first; among equal margins the earlier row first
    highest = [i for m, i in sorted((-m, i) for m, i in rows if i not in closest)][:k]
    return closest, highest


@pytest.mark.parametrize("seed", range(20))
def test_choose_equals_a_naive_sort(seed):
    rng = np.random.default_rng(seed)
    n = int(rng.integers(0, 40))
    margin = np.round(rng.normal(size=n), 1)  # rounding makes ties
    margin[rng.random(n) < 0.1] = np.nan
    success = margin > 0
    k = int(rng.integers(0, 8))
    got = choose(success, margin, k)
    closest, highest = naive_choice(success.tolist(), margin.tolist(), k)
    assert got[CLOSEST].tolist() == closest
    assert got[HIGHEST].tolist() == highest


def test_choose_a_small_case_by_hand():
    success = np.array([True, False, True, True, True])
    margin = np.array([0.3, -0.2, 0.1, 0.5, np.nan])
    got = choose(success, margin, 2)
    assert got[CLOSEST].tolist() == [2, 0]  # 0.1, then 0.3
    assert got[HIGHEST].tolist() == [3, 1]  # 0.5, then the failure at -0.2 (0.1, 0.3 taken)


def test_margin_is_the_signed_distance_from_the_boundary():
    above = Margin("height", boundary=lambda p: p["line"])
    below = Margin("peak", boundary=1.0, above=False)
    np.testing.assert_array_equal(above.of(np.array([0.5, 0.25]), {"line": 0.375}), [0.125, -0.125])
    np.testing.assert_array_equal(below.of(np.array([0.25, 1.5]), {}), [0.75, -0.5])


@pytest.fixture(scope="module")
def cartpole():
    return load_task(CARTPOLE_TASK, repo_root=REPO_ROOT)


def test_the_cartpole_margin_equals_a_step_by_step_reading_of_its_episodes(cartpole):
    """1 - the largest of |angle| / 0.25 rad and |x| / 1 m over the last second (500 steps of
    2 ms), read from the physics state step by step; its sign is the success test's."""
    rng = np.random.default_rng(3)
    values = {p.name: rng.uniform(p.low, p.high, 24) for p in cartpole.state_parameters}
    [batch] = iter_batches(
        BoundTask.of(cartpole),
        values,
        {"latency": 0.02},
        thresholds={"fall_angle": 0.5},
        batch_size=24,
    )
    table = pa.table({c: batch.outcome[c] for c in ("success", "peak_limit_fraction")})
    table = table.append_column("state_id", pa.array(np.arange(24)))
    got = margins(
        cartpole.margin,
        table,
        cartpole.parameters({"latency": 0.02}),
        source=str(cartpole.source),
        where="a test",
    )
    for i in range(24):
        x, angle = batch.episodes.physics[i, -500:, 1], batch.episodes.physics[i, -500:, 2]
        peak = max(max(abs(a) / 0.25, abs(c) / 1.0) for a, c in zip(angle, x, strict=True))
        assert got[i] == pytest.approx(1.0 - peak, abs=1e-15)
        assert (got[i] > 0) == bool(batch.outcome["success"][i])
    assert 0 < batch.outcome["success"].mean() < 1  # both signs were checked


def test_a_margin_that_disagrees_with_success_is_one_line_naming_the_task(cartpole):
    table = pa.table(
        {
            "state_id": [0, 1, 2],
            "success": [True, True, False],
            "peak_limit_fraction": [0.5, 1.2, 2.0],  # state 1 passed beyond the limits
        }
    )
    with pytest.raises(ValueError) as err:
        margins(
            cartpole.margin,
            table,
            {},
            source=str(cartpole.source),
            where="seed-1.parquet of cartpole/tuned",
        )
    message = str(err.value)
    assert "\n" not in message
    assert message.startswith(f"{cartpole.source}: margin: state 1 of seed-1.parquet")
    assert "success True but margin -0.2" in message


def test_a_margin_naming_no_measure_is_refused_at_load(tmp_path):
    folder = tmp_path / "cartpole"
    shutil.copytree(REPO_ROOT / "tasks" / "cartpole_latency", folder)
    source = folder / "task.py"
    text = source.read_text()
    assert 'Margin("peak_limit_fraction"' in text
    source.write_text(text.replace('Margin("peak_limit_fraction"', 'Margin("peak_fraction"'))
    with pytest.raises(TaskError) as err:
        load_task(source)
    assert str(err.value).startswith(f"{source}: margin: expected the name of one of")
    assert "got 'peak_fraction'" in str(err.value)


def test_the_scaffolds_margin_agrees_with_its_success_test(tmp_path):
    """`mjtrial new-task`'s task declares a margin; on episodes that both pass and fail, every
    sign is its success test's (`margins` raises otherwise)."""
    from mjtrial.cli.scaffold import new_task

    new_task("slide", repo_root=tmp_path)
    task = load_task(tmp_path / "tasks" / "slide" / "task.py")
    rng = np.random.default_rng(0)
    values = {p.name: rng.uniform(p.low, p.high, 40) for p in task.state_parameters}
    condition = {"push_force": 4.0, "push_time": 0.25}
    outcomes = {"success": [], "distance_from_line": []}
    for force in (1.0, 4.0, 8.0):
        condition["push_force"] = force
        [batch] = iter_batches(
            BoundTask.of(task), values, condition, thresholds={"short_by": 0.1}, batch_size=40
        )
        for key in outcomes:
            outcomes[key].append(batch.outcome[key])
    table = pa.table({k: np.concatenate(v) for k, v in outcomes.items()})
    table = table.append_column("state_id", pa.array(np.arange(table.num_rows)))
    got = margins(
        task.margin, table, task.parameters(condition), source="the scaffold", where="a test"
    )
    success = table.column("success").to_numpy(zero_copy_only=False)
    assert 0 < success.mean() < 1
    np.testing.assert_array_equal(got, 0.05 - table.column("distance_from_line").to_numpy())
