"""A benchmark's training job (mjtrial.stages.train): on development states only, refused on
any other states file; a stamped parameter file whose parameters run as recorded."""

from __future__ import annotations

import json

import numpy as np
import pytest
from conftest import REPO_ROOT

from mjtrial import provenance
from mjtrial.benchmark.config import check_benchmark_config, train_slice
from mjtrial.config import read_config_file
from mjtrial.sim import engine
from mjtrial.stages.condition import condition_task, thresholds_of
from mjtrial.stages.rollout import read_state_values
from mjtrial.stages.stamping import config_slice
from mjtrial.stages.states import build_states
from mjtrial.stages.train import train_method

SOURCE = "config/benchmark.yaml"
# 12 development states here, not 200, and the least budget that tunes them: 6 candidates x 6
# states for one generation, 3 finalists x 12 states (a smaller budget than the config check
# allows)
N_STATES = 12
BUDGET = 6 * 6 + 3 * N_STATES


@pytest.fixture(scope="module")
def setup(tmp_path_factory):
    folder = tmp_path_factory.mktemp("train")
    config = read_config_file(REPO_ROOT / SOURCE)
    tasks = check_benchmark_config(config, source=SOURCE)
    config["benchmark"]["methods"]["tuned"]["budget"] = BUDGET
    config["benchmark"]["methods"]["tuned"]["episodes_per_candidate"] = 6
    experiment = dict(tasks["gantry_lift"].config)
    experiment["states"] = {**experiment["states"], "n": N_STATES}
    states = config_slice("states", experiment)
    build_states(states_slice=states, output=folder / "development.parquet", development=True)
    build_states(states_slice=states, output=folder / "evaluation.parquet")
    model = REPO_ROOT / experiment["model"]
    return folder, config, tasks, model


def test_a_tuned_method_writes_a_stamped_parameter_file_that_runs_as_recorded(setup):
    folder, config, tasks, model = setup
    out = folder / "tuned-gantry-1.json"
    sl = train_slice(config, tasks, "gantry_lift", "tuned", 1)
    train_method(
        development_states=folder / "development.parquet",
        model_file=model,
        train_slice=sl,
        output=out,
        rule="train:tuned:gantry_lift:1",
    )
    record = json.loads(out.read_text())
    stamp = provenance.read_stamp(out)
    assert stamp["rule"] == "train:tuned:gantry_lift:1" and stamp["seeds"] == {"training": 1}
    recorded = stamp["inputs"]["development_states"]
    assert recorded["sha256"] == provenance.file_sha256(folder / "development.parquet")
    assert record["episodes_used"] <= BUDGET and record["budget_episodes"] == BUDGET
    assert 0.15 <= record["parameters"]["lift_time"] <= 1.5
    # The recorded score is the rate of the recorded parameters on every development state,
    # run here directly through the engine.
    bound = condition_task(sl, model)
    values = read_state_values(folder / "development.parquet", bound.task)
    values.pop("state_id")
    success = np.concatenate(
        [
            b.outcome["success"]
            for b in engine.iter_batches(
                bound, values, record["parameters"], thresholds=thresholds_of(bound, sl)
            )
        ]
    )
    assert record["score_on_development"] == pytest.approx(success.mean())


def test_a_method_with_nothing_to_tune_spends_nothing(setup):
    folder, config, tasks, model = setup
    out = folder / "fixed.json"
    train_method(
        development_states=folder / "development.parquet",
        model_file=model,
        train_slice=train_slice(config, tasks, "gantry_lift", "as_designed", 3),
        output=out,
    )
    record = json.loads(out.read_text())
    assert record["episodes_used"] == 0 and record["parameters"]["lift_time"] == 0.15


def test_training_on_evaluation_states_is_refused_and_writes_nothing(setup):
    folder, config, tasks, model = setup
    out = folder / "cheat.json"
    with pytest.raises(ValueError, match="not development states"):
        train_method(
            development_states=folder / "evaluation.parquet",
            model_file=model,
            train_slice=train_slice(config, tasks, "gantry_lift", "tuned", 1),
            output=out,
        )
    assert not out.exists()


def test_evaluating_on_development_states_is_refused_and_writes_nothing(setup):
    from mjtrial.stages.evaluate import evaluate_method

    folder, config, tasks, model = setup
    parameters = folder / "fixed-for-evaluation.json"
    train_method(
        development_states=folder / "development.parquet",
        model_file=model,
        train_slice=train_slice(config, tasks, "gantry_lift", "as_designed", 1),
        output=parameters,
    )
    out = folder / "evaluation-on-development.parquet"
    with pytest.raises(ValueError, match="not evaluation states"):
        evaluate_method(
            states=folder / "development.parquet",
            parameters=parameters,
            model_file=model,
            evaluate_slice={"task": "tasks/gantry_lift/task.py"},
            output=out,
        )
    assert not out.exists()


@pytest.mark.parametrize(
    ("rule", "kind"),
    [
        ("states", "evaluation"),
        ("states:development", "development"),
        ("states:evaluation:gantry_lift", "evaluation"),
        ("states:development:gantry_lift", "development"),
        # a task named "development": its evaluation states are still evaluation states
        ("states:evaluation:development", "evaluation"),
        ("rollout:fast#00000", None),
        ("states:other", None),
        (None, None),
    ],
)
def test_the_kind_of_states_is_read_from_the_stamps_rule(rule, kind):
    from mjtrial.stages.states import drawn_as

    assert drawn_as(rule) == kind


def test_a_benchmark_tasks_states_are_refused_by_kind_whatever_the_task_is_called(setup):
    """A benchmark stamps each task's states with the task's name (one crate job per task);
    a task called "development" does not make its evaluation states trainable."""
    from mjtrial.stages.states import states_rule

    folder, config, tasks, model = setup
    experiment = dict(tasks["gantry_lift"].config)
    experiment["states"] = {**experiment["states"], "n": N_STATES}
    states = folder / "evaluation-of-a-task-called-development.parquet"
    rule = states_rule(development=False, task="development")
    build_states(states_slice=config_slice("states", experiment), output=states, rule=rule)
    assert provenance.read_stamp(states)["rule"] == "states:evaluation:development"
    out = folder / "cheat-by-name.json"
    with pytest.raises(ValueError, match="not development states"):
        train_method(
            development_states=states,
            model_file=model,
            train_slice=train_slice(config, tasks, "gantry_lift", "tuned", 1),
            output=out,
        )
    assert not out.exists()
