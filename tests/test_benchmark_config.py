"""The benchmark's config (config/benchmark.yaml): the shipped one is runnable; every problem
is one line naming the file, the key and what was expected, before any work."""

from __future__ import annotations

import copy
import math
import shutil

import pytest
import yaml
from conftest import REPO_ROOT

from mjtrial.benchmark.config import check_benchmark_config, is_benchmark
from mjtrial.config import ConfigError, read_config_file

SOURCE = "config/benchmark.yaml"
SHIPPED = read_config_file(REPO_ROOT / SOURCE)


def test_the_shipped_benchmark_is_runnable():
    tasks = check_benchmark_config(SHIPPED, source=SOURCE)
    assert list(tasks) == ["gantry_lift", "cartpole_latency"]
    assert tasks["cartpole_latency"].condition == {"latency": 0.02}
    assert tasks["gantry_lift"].task.name == "gantry_lift"
    # the MLP's training seeds are its files, each named by its seed; not run on the gantry
    assert tasks["cartpole_latency"].policies == {
        "mlp_es": {s: f"policies/cartpole_mlp/seed-{s}.onnx" for s in (1, 2, 3, 4, 5)}
    }
    assert tasks["gantry_lift"].policies == {}
    assert is_benchmark(SHIPPED) and not is_benchmark(
        read_config_file(REPO_ROOT / "config/config.yaml")
    )


def edited(edit):
    config = copy.deepcopy(SHIPPED)
    edit(config["benchmark"])
    return config


def _set(path, value):
    def edit(bench):
        node = bench
        for part in path[:-1]:
            node = node[part]
        node[path[-1]] = value

    return edit


def _delete(path):
    def edit(bench):
        node = bench
        for part in path[:-1]:
            node = node[part]
        del node[path[-1]]

    return edit


TUNE = ("methods", "tuned", "tasks", "gantry_lift", "tune")
MLP_TASKS = ("methods", "mlp_es", "tasks")
MLP_POLICY = "benchmark.methods.mlp_es.tasks.cartpole_latency.policy"
CASES = {
    "headline": (
        _set(("headline",), "best_seed"),
        "benchmark.headline: expected one of ['episode_mean', 'task_mean'], got 'best_seed'",
    ),
    "two seeds reported": (
        _set(("seeds",), [1, 2]),
        "benchmark.seeds: expected at least 3 training seeds for a reported result",
    ),
    "two seeds for a development decision": (
        lambda bench: (_set(("seeds",), [1, 2])(bench), bench.update(result="development")),
        "benchmark.seeds: expected at least 3 training seeds for a development result (5 or "
        "more to report it as more than a development decision), got 2",
    ),
    "repeated seed": (_set(("seeds",), [1, 1, 2]), "benchmark.seeds: "),
    "unknown tuned parameter": (
        _set(TUNE, {"lift_speed": [0.1, 1.0]}),
        "benchmark.methods.tuned.tasks.gantry_lift.tune.lift_speed: not a protocol parameter",
    ),
    "tuned beyond the task's bounds": (
        _set(TUNE, {"lift_time": [0.15, 20.0]}),
        "benchmark.methods.tuned.tasks.gantry_lift.tune.lift_time: expected within the task's "
        "bounds (0, 10], got [0.15, 20]",
    ),
    "reversed bounds": (
        _set(TUNE, {"lift_time": [1.5, 0.15]}),
        "benchmark.methods.tuned.tasks.gantry_lift.tune.lift_time: expected low < high",
    ),
    "a method without a task": (
        _delete(("methods", "as_designed", "tasks", "cartpole_latency")),
        "benchmark.methods.as_designed.tasks.cartpole_latency: missing; expected what the "
        "method does on every task ('none' where it does not apply)",
    ),
    "a method on no task": (
        _set(MLP_TASKS + ("cartpole_latency",), "none"),
        "benchmark.methods.mlp_es.tasks: expected at least one task the method runs on",
    ),
    "a task neither an entry nor none": (
        _set(MLP_TASKS + ("gantry_lift",), "skip"),
        "benchmark.methods.mlp_es.tasks.gantry_lift: expected one of ['none'], got 'skip'",
    ),
    "a glob matching fewer files than seeds": (
        _set(("seeds",), [1, 2, 3, 4, 5, 6]),
        f"{MLP_POLICY}: 'policies/cartpole_mlp/seed-*.onnx': expected one file per training seed "
        "[1, 2, 3, 4, 5, 6], each with its seed as the only number of its name, got 5: "
        "policies/cartpole_mlp/seed-1.onnx, policies/cartpole_mlp/seed-2.onnx, ",
    ),
    "a glob whose files are not the seeds": (
        _set(("seeds",), [1, 2, 3, 4, 6]),
        f"{MLP_POLICY}: 'policies/cartpole_mlp/seed-*.onnx': expected one file per training seed "
        "[1, 2, 3, 4, 6], each with its seed as the only number of its name, got 5: ",
    ),
    "a glob matching no file": (
        _set(MLP_TASKS + ("cartpole_latency",), {"policy": "policies/nowhere/seed-*.onnx"}),
        f"{MLP_POLICY}: 'policies/nowhere/seed-*.onnx': expected one file per training seed "
        "[1, 2, 3, 4, 5], each with its seed as the only number of its name, got 0: no file",
    ),
    "a policy file trained for another task": (
        _set(MLP_TASKS + ("gantry_lift",), {"policy": "policies/cartpole_mlp/seed-*.onnx"}),
        "benchmark.methods.mlp_es.tasks.gantry_lift.policy: policies/cartpole_mlp/policy.yaml: ",
    ),
    "a policy method that tunes": (
        _set(
            MLP_TASKS + ("cartpole_latency",),
            {"policy": "policies/cartpole_mlp/seed-*.onnx", "tune": {"latency": [0.0, 0.05]}},
        ),
        "benchmark.methods.mlp_es.tasks.cartpole_latency.tune: a method that runs policy files "
        "tunes nothing; expected no tune",
    ),
    "a task no benchmark task": (
        _set(("methods", "as_designed", "tasks", "pendulum"), {}),
        "benchmark.methods.as_designed.tasks.pendulum: not a task of the benchmark",
    ),
    "unequal budgets without a reason": (
        _delete(("unequal_budgets",)),
        "benchmark.unequal_budgets: missing; the methods' budgets differ",
    ),
    "a tuning method without a budget": (
        _set(("methods", "tuned", "budget"), 0),
        "benchmark.methods.tuned.budget: expected a budget of episodes > 0",
    ),
    "a budget too small to tune": (
        _set(("methods", "tuned", "budget"), 500),
        # 6 candidates x 16 states, then 3 finalists x 200 development states
        "benchmark.methods.tuned.budget: expected at least 696 episodes to tune on gantry_lift",
    ),
    "a budget beyond any run's cost": (
        _set(("methods", "tuned", "budget"), 10**20),
        "benchmark.methods.tuned.budget: expected <= 1000000, got 100000000000000000000",
    ),
    "more episodes per candidate than any budget": (
        _set(("methods", "tuned", "episodes_per_candidate"), 10**20),
        "benchmark.methods.tuned.episodes_per_candidate: expected <= 1000000",
    ),
    "a fixed method with a budget": (
        _set(("methods", "as_designed", "budget"), 400),
        "benchmark.methods.as_designed.budget: expected 0 for a method that tunes nothing",
    ),
    "a fixed value beyond the bounds": (
        _set(("methods", "as_designed", "tasks", "gantry_lift", "fixed"), {"lift_time": -1.0}),
        "benchmark.methods.as_designed.tasks.gantry_lift.fixed.lift_time: expected within",
    ),
    "an unknown condition parameter": (
        _set(("tasks", "cartpole_latency", "condition"), {"latncy": 0.02}),
        "benchmark.tasks.cartpole_latency.condition.latncy: not a protocol parameter",
    ),
    "a missing experiment config": (
        _set(("tasks", "gantry_lift", "experiment"), "config/nowhere.yaml"),
        "benchmark.tasks.gantry_lift.experiment: expected an experiment config file, got "
        "'config/nowhere.yaml'",
    ),
    "not finite": (
        _set(("analysis", "confidence"), math.nan),
        "benchmark.analysis.confidence: expected a finite number, got nan",
    ),
    "unknown key": (
        _set(("sedes",), [1, 2, 3]),
        "benchmark.sedes: unknown key",
    ),
}


@pytest.mark.parametrize("case", list(CASES))
def test_a_bad_benchmark_config_is_one_line_naming_the_key(case):
    edit, expected = CASES[case]
    with pytest.raises(ConfigError) as err:
        check_benchmark_config(edited(edit), source=SOURCE)
    message = str(err.value)
    assert "\n" not in message
    assert message.startswith(f"{SOURCE}: {expected}"), message


def test_a_task_whose_own_config_is_broken_is_named_with_its_key(tmp_path):
    for name in ("config", "models", "tasks"):
        shutil.copytree(REPO_ROOT / name, tmp_path / name)
    broken = yaml.safe_load((tmp_path / "config" / "config.yaml").read_text())
    broken["states"]["n"] = 0
    (tmp_path / "config" / "config.yaml").write_text(yaml.safe_dump(broken))
    with pytest.raises(ConfigError) as err:
        check_benchmark_config(SHIPPED, source=SOURCE, repo_root=tmp_path)
    message = str(err.value)
    assert message.startswith(
        f"{SOURCE}: benchmark.tasks.gantry_lift.experiment: its config is not runnable: "
        "config/config.yaml: states.n: expected >= 1"
    ), message
    assert "\n" not in message
