"""Config errors are one line naming the file, the key and the expectation (unit level; the
pipeline's end-to-end cases are in test_trust.py)."""

from __future__ import annotations

import copy

import pytest
import yaml
from conftest import REPO_ROOT

from mjtrial.config import ConfigError, check_config, read_config_file

SOURCE = "config/config.yaml"
BASE = yaml.safe_load((REPO_ROOT / SOURCE).read_text())


def edited(edit) -> dict:
    config = copy.deepcopy(BASE)
    edit(config)
    return config


# (case, edit of the committed config, the whole message after "config/config.yaml: ")
SCHEMA_CASES = [
    (
        "missing top-level key",
        lambda c: c.pop("recording"),
        "recording: missing; this key is required",
    ),
    (
        "missing nested key",
        lambda c: c["conditions"]["fast"].pop("lift_time"),
        "conditions.fast.lift_time: missing; this key is required",
    ),
    (
        "misspelled nested key",
        lambda c: c["states"].update(seeed=1),
        "states.seeed: unknown key; expected one of ['development_seed', 'distributions', 'n', "
        "'ranges', 'seed']",
    ),
    (
        "wrong type",
        lambda c: c["states"].update(n="many"),
        "states.n: expected integer, got 'many'",
    ),
    ("below minimum", lambda c: c["states"].update(n=0), "states.n: expected >= 1, got 0"),
    (
        "an unknown distribution",
        lambda c: c["states"].update(
            distributions={"dx": {"kind": "laplace", "mean": 0, "std": 1}}
        ),
        "states.distributions.dx.kind: expected one of ['normal', 'truncated_normal'], got "
        "'laplace'",
    ),
    (
        "at exclusive minimum",
        lambda c: c["analysis"].update(confidence=0),
        "analysis.confidence: expected > 0, got 0",
    ),
    (
        "above exclusive maximum",
        lambda c: c["analysis"].update(confidence=1.5),
        "analysis.confidence: expected < 1, got 1.5",
    ),
    (
        "array item",
        lambda c: c["states"]["ranges"].update(mass=[-0.1, 0.6]),
        "states.ranges.mass[0]: expected > 0, got -0.1",
    ),
    (
        "too few items",
        lambda c: c["analysis"]["bands"].update(mass=[0.05]),
        "analysis.bands.mass: expected at least 2 items, got [0.05]",
    ),
    (
        "not in enum",
        lambda c: c["design"]["falsifier"].update(statistic="median"),
        "design.falsifier.statistic: expected one of ['paired_difference'], got 'median'",
    ),
    (
        "empty string",
        lambda c: c["design"].update(question=""),
        "design.question: expected a non-empty string, got ''",
    ),
    (
        "badly named condition",
        lambda c: c["conditions"].update({"very-slow": {"lift_time": 3.0}}),
        "conditions: expected a name matching ^[A-Za-z][A-Za-z0-9_]*$, got 'very-slow'",
    ),
]

# Checks a schema cannot express.
SEMANTIC_CASES = [
    (
        "a sweep whose reference lies inside it, without a direction",
        lambda c: c["sweep"].update(reference=0.6),
        "sweep.toward: expected smaller or larger: the reference 0.6 lies inside the sweep, so "
        "which way values cost must be said",
    ),
    (
        "a sweep direction that is no direction",
        lambda c: c["sweep"].update(toward="down"),
        "sweep.toward: expected one of ['smaller', 'larger'], got 'down'",
    ),
    (
        "falsifier names an unknown condition",
        lambda c: c["design"]["falsifier"].update(baseline="medium"),
        "design.falsifier.baseline: expected one of the conditions ['fast', 'slow'], got 'medium'",
    ),
    (
        "falsifier compares a condition with itself",
        lambda c: c["design"]["falsifier"].update(baseline="slow"),
        "design.falsifier.baseline: expected a condition other than the treatment",
    ),
    (
        "inverted range",
        lambda c: c["states"]["ranges"].update(yaw=[0.6, -0.6]),
        "states.ranges.yaw: expected [low, high] with low < high, got [0.6, -0.6]",
    ),
    (
        "same development and evaluation seed",
        lambda c: c["states"].update(development_seed=c["states"]["seed"]),
        "states.development_seed: expected a seed other than states.seed (development and "
        "evaluation states must be disjoint)",
    ),
    (
        "bands not covering the range",
        lambda c: c["analysis"]["bands"].update(mass=[0.1, 0.3, 0.6]),
        "analysis.bands.mass: expected edges covering the range of mass [0.05, 0.6], "
        "got [0.1, 0.3, 0.6]",
    ),
    (
        "task file not found",
        lambda c: c.update(task="tasks/nowhere/task.py"),
        "task: tasks/nowhere/task.py: task file not found",
    ),
    (
        "a state parameter of the task without a range",
        lambda c: c["states"]["ranges"].pop("yaw"),
        "states.ranges.yaw: missing; expected a range for each of ['dx', 'dy', 'yaw', 'mass']",
    ),
    (
        "a range for no state parameter of the task",
        lambda c: c["states"]["ranges"].update(spin=[0.0, 1.0]),
        "states.ranges.spin: not a state parameter of the task; expected "
        "['dx', 'dy', 'yaw', 'mass']",
    ),
    (
        "a task of another model",
        lambda c: c.update(task="tasks/cartpole_latency/task.py"),
        "task: its model is tasks/cartpole_latency/cartpole.xml; expected the config's model "
        "models/gantry_gripper/scene.xml",
    ),
    (
        "a distribution of no state parameter",
        lambda c: c["states"].update(
            distributions={"roll": {"kind": "normal", "mean": 0, "std": 1}}
        ),
        "states.distributions.roll: not a state parameter of the task; expected one of "
        "['dx', 'dy', 'yaw', 'mass']",
    ),
    (
        "a normal mass",
        lambda c: c["states"].update(
            distributions={"mass": {"kind": "normal", "mean": 0.3, "std": 0.1}}
        ),
        "states.distributions.mass: a normal draws masses at or below 0; expected truncated_normal",
    ),
    (
        "missing model file",
        lambda c: c.update(model="models/nowhere/scene.xml"),
        "model: expected an existing model file, got 'models/nowhere/scene.xml' (not found)",
    ),
]


@pytest.mark.parametrize(
    ("case", "edit", "message"),
    SCHEMA_CASES + SEMANTIC_CASES,
    ids=[c[0] for c in SCHEMA_CASES + SEMANTIC_CASES],
)
def test_bad_config_is_one_line_naming_file_key_and_expectation(case, edit, message):
    with pytest.raises(ConfigError) as err:
        check_config(edited(edit), source=SOURCE, repo_root=REPO_ROOT)
    assert str(err.value) == f"{SOURCE}: {message}"


def test_unknown_top_level_key_lists_the_known_ones():
    with pytest.raises(ConfigError) as err:
        check_config(edited(lambda c: c.update(experimnt="x")), source=SOURCE)
    assert str(err.value).startswith(f"{SOURCE}: experimnt: unknown key; expected one of [")
    assert "'experiment'" in str(err.value)


def test_committed_config_passes():
    check_config(copy.deepcopy(BASE), source=SOURCE, repo_root=REPO_ROOT)


def test_duplicate_key_is_named_with_its_line(tmp_path):
    path = tmp_path / "config.yaml"
    path.write_text("conditions:\n  slow: {lift_time: 1.5}\n  slow: {lift_time: 3.0}\n")
    with pytest.raises(ConfigError, match=r"conditions\.slow: duplicate key \(line 3\)"):
        read_config_file(path)


# The schema of conditions, thresholds, a sweep's parameter and the bands is the task's.
CARTPOLE_SOURCE = "config/cartpole_latency.yaml"
CARTPOLE = yaml.safe_load((REPO_ROOT / CARTPOLE_SOURCE).read_text())
# a condition's keys: the task's protocol parameters, `model` (its edits of the model) and
# `policy` (a policy file)
CARTPOLE_KEYS = (
    "['angle_gain_scale', 'cart_gain_scale', 'cart_rate_gain_scale', 'control_period', "
    "'duration', 'latency', 'model', 'policy', 'rate_gain_scale']"
)


def test_the_cartpole_config_is_valid():
    check_config(copy.deepcopy(CARTPOLE), source=CARTPOLE_SOURCE, repo_root=REPO_ROOT)


@pytest.mark.parametrize("source", ["config/reacher_goal.yaml", "config/reacher_damping.yaml"])
def test_the_reacher_configs_are_valid(source):
    """The goal-conditioned reach and the model-change question (a condition editing joints)."""
    check_config(yaml.safe_load((REPO_ROOT / source).read_text()), source=source)


@pytest.mark.parametrize(
    ("base", "source", "edit", "message"),
    [
        (
            BASE,
            SOURCE,
            lambda c: c["conditions"]["fast"].update(latency=0.02),
            "conditions.fast.latency: unknown key; expected one of ['close_time', "
            "'gripper_closed', 'hold_time', 'lift_time', 'model', 'policy', 'pre_close_time', "
            "'settle_time']",
        ),
        (
            CARTPOLE,
            CARTPOLE_SOURCE,
            lambda c: c["conditions"]["no_latency"].update(lift_time=1.5),
            f"conditions.no_latency.lift_time: unknown key; expected one of {CARTPOLE_KEYS}",
        ),
        (
            CARTPOLE,
            CARTPOLE_SOURCE,
            lambda c: c["conditions"]["no_latency"].update(latency=0.5),
            "conditions.no_latency.latency: expected <= 0.1, got 0.5",
        ),
        (
            CARTPOLE,
            CARTPOLE_SOURCE,
            lambda c: c["failure_taxonomy"].update(lifted_height=0.03),
            "failure_taxonomy.lifted_height: unknown key; expected one of ['fall_angle']",
        ),
        (
            CARTPOLE,
            CARTPOLE_SOURCE,
            lambda c: c["failure_taxonomy"].update(fall_angle=0.1),
            "failure_taxonomy.fall_angle: expected >= 0.25, got 0.1",
        ),
        (
            CARTPOLE,
            CARTPOLE_SOURCE,
            lambda c: c["sweep"].update(parameter="lift_time"),
            "sweep.parameter: expected one of ['latency', 'duration', 'control_period', "
            "'cart_gain_scale', 'angle_gain_scale', 'cart_rate_gain_scale', 'rate_gain_scale'], "
            "got 'lift_time'",
        ),
        (
            CARTPOLE,
            CARTPOLE_SOURCE,
            lambda c: c["analysis"]["bands"].update(mass=[0.05, 0.3]),
            "analysis.bands.mass: unknown key; expected one of ['abs_pole_angle', "
            "'abs_pole_mass', 'abs_pole_rate', 'abs_push_force', 'abs_push_time', 'pole_angle', "
            "'pole_mass', 'pole_rate', 'push_force', 'push_time']",
        ),
    ],
    ids=[
        "a cart-pole parameter in the gantry's condition",
        "a gantry parameter in the cart-pole's condition",
        "a cart-pole parameter beyond its bound",
        "a gantry threshold in the cart-pole's taxonomy",
        "a cart-pole threshold below its bound",
        "a sweep of another task's parameter",
        "a band of another task's parameter",
    ],
)
def test_the_task_declares_what_conditions_thresholds_sweeps_and_bands_hold(
    base, source, edit, message
):
    config = copy.deepcopy(base)
    edit(config)
    with pytest.raises(ConfigError) as err:
        check_config(config, source=source, repo_root=REPO_ROOT)
    assert str(err.value) == f"{source}: {message}"


def test_a_configfile_naming_an_experiment_replaces_the_default(tmp_path):
    from mjtrial.config import run_configuration

    default = REPO_ROOT / SOURCE
    cartpole = REPO_ROOT / CARTPOLE_SOURCE
    base, command_line, config = run_configuration(
        [cartpole], ["states={n: 40}"], {"states": "{n: 40}"}, default=default
    )
    assert base == cartpole
    assert command_line == {"states": {"n": 40}}
    assert config["conditions"] == CARTPOLE["conditions"]  # no gantry condition mixed in
    assert config["states"] == {**CARTPOLE["states"], "n": 40}
    assert set(config) == set(CARTPOLE)
    # a configfile of values only goes on top of the default, as Snakemake merges it
    small = tmp_path / "small.yaml"
    small.write_text("states:\n  n: 12\n")
    base, command_line, config = run_configuration([small], [], {}, default=default)
    assert base == default
    assert command_line == {"states": {"n": 12}}
    assert config["conditions"] == BASE["conditions"]
    assert config["states"] == {**BASE["states"], "n": 12}


def _with_comparisons(comparisons, extra_condition=True):
    def edit(config):
        if extra_condition:
            config["conditions"]["medium"] = {"lift_time": 0.5}
        config["analysis"]["comparisons"] = comparisons

    return edit


@pytest.mark.parametrize(
    ("comparisons", "message"),
    [
        (
            {"against": "fastest"},
            "analysis.comparisons.against: expected one of the conditions "
            "['fast', 'medium', 'slow'], got 'fastest'",
        ),
        (
            [["medium", "fats"]],
            "analysis.comparisons[0]: expected conditions ['fast', 'medium', 'slow'], got 'fats'",
        ),
        (
            [["medium", "medium"]],
            "analysis.comparisons[0]: expected two different conditions, got ['medium', 'medium']",
        ),
        (
            [["medium", "fast"], ["fast", "medium"]],
            "analysis.comparisons[1]: ['fast', 'medium'] is listed twice",
        ),
        (
            [["fast", "slow"]],
            "analysis.comparisons[0]: the falsifier's comparison reversed; "
            "expected ['slow', 'fast'] (it is always tested, listed or not)",
        ),
        (
            {"against": "fast", "also": 1},
            "analysis.comparisons.also: unknown key; expected one of ['against']",
        ),
        ([["medium"]], "analysis.comparisons[0]: expected at least 2 items, got ['medium']"),
        ("fast", "analysis.comparisons: expected an object or an array, got 'fast'"),
    ],
)
def test_a_wrong_planned_comparison_is_one_line(comparisons, message):
    with pytest.raises(ConfigError) as err:
        check_config(edited(_with_comparisons(comparisons)), source=SOURCE, repo_root=REPO_ROOT)
    assert str(err.value) == f"{SOURCE}: {message}"


@pytest.mark.parametrize(
    "comparisons",
    [{"against": "fast"}, [["slow", "fast"], ["medium", "fast"]], [["slow", "medium"]]],
)
def test_planned_comparisons_pass(comparisons):
    check_config(edited(_with_comparisons(comparisons)), source=SOURCE, repo_root=REPO_ROOT)
