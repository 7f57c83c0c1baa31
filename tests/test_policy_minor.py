"""Small refusals and fixes around policy files (issue 34, item 14): non-finite contract
numbers, `policy check --set` out of the task's bounds and `--task` by a repository task's
name, a benchmark tune range the observation model refuses, a quantum below a reading's own
float spacing, checkpoint names with more than one number."""

from __future__ import annotations

import numpy as np
import pytest
from conftest import REPO_ROOT
from policy_graphs import tanh_mlp, write
from test_sensors import THRESHOLDS, _encoder_task, _states

from mjtrial.benchmark.config import checkpoint_files
from mjtrial.benchmark.tuning import check_search
from mjtrial.cli import main
from mjtrial.policy_files.file import PolicyFileError, load_policy_file, policy_task
from mjtrial.sim.engine import iter_batches
from mjtrial.task import BoundTask, load_task

TASK = load_task("tasks/cartpole_latency/task.py", repo_root=REPO_ROOT)
SEED_1 = "policies/cartpole_mlp/seed-1.onnx"


@pytest.mark.parametrize(
    ("changes", "message"),
    [
        (
            {"normalization": {"mean": [0.0, float("nan")], "std": [1.0, 1.0]}},
            "normalization.mean: nan",
        ),
        (
            {"normalization": {"mean": [0.0, 0.0], "std": [1.0, float("inf")]}},
            "normalization.std: inf",
        ),
        ({"control_period": float("nan")}, "control_period: nan"),
    ],
)
def test_non_finite_numbers_in_a_contract_are_one_line(tmp_path, changes, message):
    path = write(tmp_path, "net", tanh_mlp([2, 8, 1]), **changes)
    with pytest.raises(PolicyFileError) as caught:
        load_policy_file(path, TASK)
    assert str(caught.value) == f"{path.with_suffix('.yaml')}: {message}; expected finite numbers"


def test_policy_check_by_task_name_and_set_within_the_tasks_bounds(monkeypatch, capsys):
    monkeypatch.chdir(REPO_ROOT)  # as the README's command runs, from the checkout
    assert main(["policy", "check", SEED_1, "--task", "cartpole_latency"]) == 0
    assert capsys.readouterr().out.startswith(
        f"{SEED_1}: contract policies/cartpole_mlp/policy.yaml"
    )
    for given, err in [
        (
            "latency=-1",
            "cartpole_latency: --set latency=-1: expected within the task's bounds "
            "(-1.0 is less than the minimum of 0)",
        ),
        (
            "latency=0.5",
            "cartpole_latency: --set latency=0.5: expected within the task's bounds "
            "(0.5 is greater than the maximum of 0.1)",
        ),
        ("latency=nan", "--set latency=nan: expected NAME=NUMBER, a finite number"),
    ]:
        assert main(["policy", "check", SEED_1, "--task", "cartpole_latency", "--set", given]) == 2
        assert capsys.readouterr().err == f"mjtrial policy check: {err}\n"


def test_a_tune_range_the_observation_model_refuses_is_refused_by_the_check():
    task = _encoder_task()
    with pytest.raises(ValueError) as caught:
        check_search(task, {"encoder_noise": [-0.01, 0.02]}, {}, require_tuned=False)
    assert str(caught.value) == (
        "tuned.encoder_noise: observation 'cart_position': noise parameter 'encoder_noise' is "
        "-0.01; expected >= 0 (a standard deviation)"
    )
    with pytest.raises(ValueError, match=r"^tuned.encoder_dropout: .* is 1; expected a probabi"):
        check_search(task, {"encoder_dropout": [0.0, 1.0]}, {}, require_tuned=False)
    with pytest.raises(ValueError, match=r"^fixed.encoder_quantum: .* is -0.1; expected >= 0"):
        check_search(task, {}, {"encoder_quantum": -0.1}, require_tuned=False)
    check_search(task, {"encoder_noise": [0.0, 0.02]}, {"encoder_dropout": 0.5})


def test_a_quantum_below_the_readings_float_spacing_rounds_to_the_reading():
    """5e-324 (the smallest double, of which every double is a multiple): readings as with no
    rounding, bit for bit (before: x / 5e-324 overflowed and the episode failed)."""
    bound = BoundTask.of(_encoder_task())
    values = _states(bound.task, 3)
    runs = [
        next(
            iter_batches(
                bound,
                values,
                {"duration": 1.5, "encoder_noise": 0.01, "encoder_quantum": quantum},
                thresholds=THRESHOLDS,
            )
        )
        for quantum in (0.0, 5e-324)
    ]
    np.testing.assert_array_equal(runs[0].episodes.physics, runs[1].episodes.physics)
    assert (
        runs[1].outcome["failure_category"].tolist() == runs[0].outcome["failure_category"].tolist()
    )


def test_a_checkpoint_name_with_more_than_one_number_is_refused(tmp_path):
    for seed in (1, 2):
        (tmp_path / f"seed-{seed}.onnx").touch()
    (tmp_path / "seed-2.onnx").rename(tmp_path / "seed-3-v2.onnx")
    with pytest.raises(ValueError) as caught:
        checkpoint_files("seed-*.onnx", [1, 2], repo_root=tmp_path)
    assert str(caught.value) == (
        "seed-3-v2.onnx has 2 numbers in its name (3, 2); expected its training seed as the "
        "only number (seed-3.onnx: seed 3)"
    )


def test_a_column_driving_a_list_of_actuators_runs_and_is_reported(tmp_path, capsys):
    """`actuators: [[cart_motor]]` (one column, a list of actuators) gives the episodes the
    plain `[cart_motor]` gives, and `policy check` says it (before: two tracebacks)."""
    listed = write(tmp_path, "listed", tanh_mlp([2, 8, 1]), actuators=[["cart_motor"]])
    plain = write(tmp_path, "plain", tanh_mlp([2, 8, 1]))
    values = {p.name: np.linspace(p.low, p.high, 4) for p in TASK.state_parameters}
    physics = []
    for path in (listed, plain):
        bound = BoundTask.of(policy_task(TASK, load_policy_file(path, TASK)))
        [batch] = iter_batches(bound, values, {}, thresholds={"fall_angle": 0.5})
        physics.append(batch.episodes.physics)
    np.testing.assert_array_equal(physics[0], physics[1])
    task_file = str(REPO_ROOT / "tasks" / "cartpole_latency" / "task.py")
    assert main(["policy", "check", str(listed), "--task", task_file]) == 0
    assert "actuators [cart_motor] (ctrlrange); control period 0.01 s" in capsys.readouterr().out
