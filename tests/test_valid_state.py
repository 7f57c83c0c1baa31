"""Constrained initial states (`Task(valid_state=...)`): invalid draws are redrawn from the
seed by the documented rule (rounds of the plain draw, valid rows kept in order), the count is
recorded in the states stamp and the manifest, a constraint that keeps almost nothing is
refused in one line; without one the states are the plain `default_rng(seed).uniform` draw.
And band edges on a signed state parameter may be negative (its magnitude's may not)."""

from __future__ import annotations

import copy
import textwrap

import numpy as np
import pytest
import yaml
from conftest import REPO_ROOT

from mjtrial import provenance
from mjtrial.config import ConfigError, check_config
from mjtrial.design.states import draw_valid_states
from mjtrial.stages.states import REDRAWN, build_states, draw_counted_states
from mjtrial.task import NotAFunctionError, TaskError

RANGES = {"a": [-1.0, 1.0], "b": [0.0, 2.0]}


def _inside_disc(values):
    """a^2 + (b-1)^2 < 0.5: about 39 % of the box."""
    return values["a"] ** 2 + (values["b"] - 1.0) ** 2 < 0.5


def test_the_states_are_the_valid_rows_of_rounds_of_the_plain_draw_in_order():
    n, seed = 40, 11
    table, rejected = draw_valid_states(
        seed=seed, n=n, ranges=RANGES, parameters=["a", "b"], valid=_inside_disc
    )
    # the rule written out: rounds of n per parameter from one generator, valid rows in order
    rng = np.random.default_rng(seed)
    kept, invalid = [], 0
    while len(kept) < n:
        a, b = rng.uniform(-1.0, 1.0, n), rng.uniform(0.0, 2.0, n)
        for x, y in zip(a, b, strict=True):
            if len(kept) == n:
                break
            if x**2 + (y - 1.0) ** 2 < 0.5:
                kept.append((x, y))
            else:
                invalid += 1
    kept = np.array(kept)
    np.testing.assert_array_equal(table.column("a").to_numpy(), kept[:, 0])
    np.testing.assert_array_equal(table.column("b").to_numpy(), kept[:, 1])
    np.testing.assert_array_equal(table.column("state_id").to_numpy(), np.arange(n))
    assert rejected == invalid > 0
    # the first valid rows are the plain draw's own: a state drawn valid keeps its values
    plain = np.random.default_rng(seed)
    a, b = plain.uniform(-1.0, 1.0, n), plain.uniform(0.0, 2.0, n)
    first = a[a**2 + (b - 1.0) ** 2 < 0.5]
    np.testing.assert_array_equal(table.column("a").to_numpy()[: len(first)], first)


def _task_file(tmp_path, valid: str) -> str:
    """A copy of the gantry task with a `valid_state` (tmp_path/task.py)."""
    path = tmp_path / "task.py"
    path.write_text(
        textwrap.dedent(
            f"""
            import dataclasses
            from mjtrial.task import load_task

            def valid_state(values):
                return {valid}

            TASK = dataclasses.replace(
                load_task({str(REPO_ROOT / "tasks/gantry_lift/task.py")!r}),
                valid_state=valid_state,
            )
            """
        )
    )
    return str(path)


GANTRY = yaml.safe_load((REPO_ROOT / "config" / "config.yaml").read_text())["states"]


def test_the_redraws_are_counted_in_the_states_stamp(tmp_path):
    task = _task_file(tmp_path, "values['dx'] * values['dy'] > 0")  # half of the states
    states = {**GANTRY, "n": 30, "task": task}
    table = build_states(states_slice=states, output=tmp_path / "states.parquet")
    dx, dy = table.column("dx").to_numpy(), table.column("dy").to_numpy()
    assert table.num_rows == 30 and (dx * dy > 0).all()
    stamp = provenance.read_stamp(tmp_path / "states.parquet")
    _, _, redrawn = draw_counted_states(states, repo_root=REPO_ROOT)
    assert stamp["extra"][REDRAWN] == redrawn
    assert redrawn["evaluation"] > 0 and redrawn["development"] > 0


def test_a_constraint_that_keeps_almost_nothing_is_refused_in_one_line(tmp_path):
    task = _task_file(tmp_path, "values['mass'] < 0.053")  # about 0.5 % of [0.05, 0.6]
    with pytest.raises(TaskError) as err:
        draw_counted_states({**GANTRY, "task": task}, repo_root=REPO_ROOT)
    message = str(err.value)
    assert message.startswith(f"{task}: valid_state: expected at least 1% of states valid, got ")
    assert "of the first 10,000 drawn" in message and "\n" not in message


def test_a_constraint_answering_the_wrong_shape_is_named(tmp_path):
    task = _task_file(tmp_path, "values['mass'][:3] > 0")
    with pytest.raises(TaskError, match=r"valid_state: expected \(10000,\) booleans"):
        draw_counted_states({**GANTRY, "task": task}, repo_root=REPO_ROOT)


def test_without_a_constraint_the_states_are_the_plain_draw():
    states = {**GANTRY, "task": "tasks/gantry_lift/task.py"}
    table, tuning, redrawn = draw_counted_states(states, repo_root=REPO_ROOT)
    assert redrawn is None
    for drawn, seed in ((table, GANTRY["seed"]), (tuning, GANTRY["development_seed"])):
        rng = np.random.default_rng(seed)
        for name in ("dx", "dy", "yaw", "mass"):
            expected = rng.uniform(*GANTRY["ranges"][name], GANTRY["n"])
            np.testing.assert_array_equal(drawn.column(name).to_numpy(), expected)


CONFIG = yaml.safe_load((REPO_ROOT / "config" / "config.yaml").read_text())


def _with_bands(**bands) -> dict:
    config = copy.deepcopy(CONFIG)
    config["analysis"]["bands"] = bands
    return config


def test_bands_on_a_signed_parameter_take_signed_edges_covering_its_range():
    check_config(_with_bands(dx=[-0.018, 0.0, 0.018]), repo_root=REPO_ROOT)
    with pytest.raises(ConfigError) as err:
        check_config(_with_bands(dx=[-0.01, 0.0, 0.018]), repo_root=REPO_ROOT)
    assert str(err.value) == (
        "config/config.yaml: analysis.bands.dx: expected edges covering the range of dx "
        "[-0.018, 0.018], got [-0.01, 0.0, 0.018]"
    )


def test_a_magnitudes_band_edges_stay_non_negative():
    with pytest.raises(ConfigError) as err:
        check_config(_with_bands(abs_dx=[-0.018, 0.0, 0.018]), repo_root=REPO_ROOT)
    assert (
        str(err.value) == "config/config.yaml: analysis.bands.abs_dx[0]: expected >= 0, got -0.018"
    )


# A constraint that is not a function of each state's values (issue 42, item 11): the states
# would depend on more than the seed. Each is refused in one line naming the task file and
# `valid_state`, in the states job, before any state is written.
NOT_FUNCTIONS = {
    # unseeded randomness: a third of the states, a fresh third at each call
    "unseeded": (
        "__import__('numpy').random.default_rng().random(len(values['dx'])) < 0.5",
        "asked twice about the same 10,000 states",
    ),
    # the answer depends on the state's place in the batch
    "place": (
        "__import__('numpy').arange(len(values['dx'])) % 2 == 0",
        "asked about the same 10,000 states in reverse order",
    ),
    # the answer depends on the batch's size
    "size": (
        "(values['dx'] > 0) == (len(values['dx']) > 500)",
        "asked about the first 100 states alone",
    ),
}


@pytest.mark.parametrize("kind", sorted(NOT_FUNCTIONS))
def test_a_constraint_that_is_not_a_function_of_the_state_is_refused_in_one_line(tmp_path, kind):
    rule, how = NOT_FUNCTIONS[kind]
    task = _task_file(tmp_path, rule)
    with pytest.raises(NotAFunctionError) as err:  # a TaskError: irreproducible for verify
        draw_counted_states({**GANTRY, "task": task}, repo_root=REPO_ROOT)
    message = str(err.value)
    assert message.startswith(
        f"{task}: valid_state: not a function of each state's values: {how}, it answered "
    )
    assert "\n" not in message


def test_a_constraint_that_calls_on_its_module_state_is_refused():
    """A counter in the module: the second call answers otherwise than the first."""
    calls = []

    def by_call(values):
        calls.append(1)
        return np.full(len(values["a"]), len(calls) % 2 == 1) | (values["a"] > 0)

    with pytest.raises(ValueError, match="asked twice about the same 10,000 states, it "):
        draw_valid_states(seed=1, n=5, ranges=RANGES, parameters=["a", "b"], valid=by_call)


def test_a_constraint_that_rejects_every_round_of_n_stops_in_one_line():
    """A rule that answers the probe's batches (10,000 and 100 states) but rejects every
    round of n = 7: the draw gives up after 20 times the rounds the probe's acceptance
    expects, instead of looping for ever."""
    asked = []

    def batch_rule(values):
        asked.append(len(values["a"]))
        return np.full(len(values["a"]), len(values["a"]) != 7) & (values["a"] > 0)

    with pytest.raises(ValueError) as err:
        draw_valid_states(seed=1, n=7, ranges=RANGES, parameters=["a", "b"], valid=batch_rule)
    rate = np.mean(np.random.default_rng(1).uniform(-1.0, 1.0, 10_000) > 0)  # the probe's
    rounds = 20 * int(np.ceil(1 / rate))
    assert str(err.value) == (
        f"kept 0 of 7 states in {rounds:,} rounds of 7, where the {rate:.2%} it accepted of the "
        f"first 10,000 drawn expects about {int(np.ceil(7 / rate)):,} draws; expected each "
        "state's answer from its own values alone, not the batch's size"
    )
    assert asked.count(7) == rounds


def test_verify_names_states_it_cannot_recompute_for_such_a_constraint_irreproducible(tmp_path):
    """The states of a run whose `valid_state` is not a function of the states cannot be
    recomputed: verify says so (irreproducible), never that the file was tampered with."""
    from mjtrial.files.layout import Layout
    from mjtrial.verify.recompute import _Checker

    layout = Layout(tmp_path / "results" / "x")
    rel = "results/x/states.parquet"
    checker = _Checker(layout, {"model": "m.xml"}, tmp_path, [rel], {}, "snakemake -c2")

    def recompute():
        raise NotAFunctionError("tasks/t/task.py: valid_state: not a function of each state's")

    checker.check(layout.states, recompute)
    assert checker.found.differs == {}
    assert checker.found.irreproducible == {
        rel: "cannot be recomputed: tasks/t/task.py: valid_state: not a function of each state's"
    }


def test_the_config_check_refuses_such_a_constraint_before_any_job(tmp_path):
    """The states job's probe runs in the config check too: refused when the workflow loads,
    not in the states job (after the design is registered)."""
    config = copy.deepcopy(CONFIG)
    config["task"] = _task_file(tmp_path, NOT_FUNCTIONS["unseeded"][0])
    with pytest.raises(ConfigError) as err:
        check_config(config, source="config/config.yaml", repo_root=REPO_ROOT)
    assert str(err.value).startswith(
        f"config/config.yaml: task: {config['task']}: valid_state: not a function of each "
        "state's values: asked twice about the same 10,000 states, it answered "
    )
    config["task"] = _task_file(tmp_path, "values['dx'] * values['dy'] > 0")
    check_config(config, source="config/config.yaml", repo_root=REPO_ROOT)  # a function: passes
