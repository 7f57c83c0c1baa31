"""The report's statements are true of the experiment they describe: each built-in experiment's
model and the Fetch (actuators, contacts), the nominal-state shortcut of every condition, a
comparison at its ceiling or floor, and the studies it names. The statement functions are called
directly on summaries made by `mjtrial.analysis.summarize` from outcomes written here."""

from __future__ import annotations

import re
from pathlib import Path

import mujoco
import numpy as np
import pytest
import yaml
from test_report_model import FETCH, _documented_pairs

from mjtrial.analysis import summarize
from mjtrial.report.actuators import actuator_lines
from mjtrial.report.model import collision_pairs, contact_lines
from mjtrial.report.text import _mistakes, _results, _scope_limits
from mjtrial.sim.physics import load_model
from mjtrial.stages.stamping import config_slice
from mjtrial.stats import newcombe_paired_interval
from mjtrial.task import load_task

REPO = Path(__file__).resolve().parents[1]
EXPERIMENTS = ["config.yaml", "cartpole_latency.yaml", "reacher_goal.yaml", "reacher_damping.yaml"]
BUILT_IN = [REPO / "config" / name for name in EXPERIMENTS if (REPO / "config" / name).is_file()]
UNIT = {"slide": ("m", "N"), "hinge": ("rad", "N·m")}


def _config(path: Path) -> dict:
    return yaml.safe_load(path.read_text(encoding="utf-8"))


def _models() -> list[tuple[str, Path]]:
    return [(p.stem, REPO / _config(p)["model"]) for p in BUILT_IN] + [("fetch", FETCH)]


def _check_actuator_line(model: mujoco.MjModel, i: int, line: str) -> None:
    """The line says what the compiled model says of actuator `i`, worked out here from its
    fields: a servo's target = ctrlrange / gear, a bound force = forcerange x gear or, for a
    motor, ctrlrange x gain x gear, for a position servo on a limited joint kp x (ctrlrange -
    gear x joint range) x gear."""
    name = mujoco.mj_id2name(model, mujoco.mjtObj.mjOBJ_ACTUATOR, i)
    assert line.startswith(f"  - `{name}` on ")
    gear = model.actuator_gear[i, 0]
    gain, bias = model.actuator_gainprm[i, 0], model.actuator_biasprm[i, :3]
    affine = model.actuator_biastype[i] == mujoco.mjtBias.mjBIAS_AFFINE
    position = affine and bias[1] == -gain and bias[0] == 0 and gain > 0
    if position:
        assert "position servo" in line
        if model.actuator_ctrllimited[i]:
            low, high = sorted(model.actuator_ctrlrange[i] / gear)
            assert f"target [{low:g}, {high:g}]" in line
    joint = model.actuator_trnid[i, 0]
    on_limited_joint = (
        model.actuator_trntype[i] == mujoco.mjtTrn.mjTRN_JOINT and model.jnt_limited[joint]
    )
    bounds = []
    if model.actuator_forcelimited[i]:
        bounds.append(model.actuator_forcerange[i])
    if not affine and model.actuator_ctrllimited[i]:
        bounds.append(model.actuator_ctrlrange[i] * gain)
    if position and not bias[2] and model.actuator_ctrllimited[i] and on_limited_joint:
        ctrl, q = model.actuator_ctrlrange[i], model.jnt_range[joint] * gear
        bounds.append([gain * (ctrl[0] - q[1]), gain * (ctrl[1] - q[0])])
    if bounds:
        low = max(min(b) for b in bounds)
        high = min(max(b) for b in bounds)
        low, high = sorted((low * gear, high * gear))
        assert f"force [{low + 0.0:g}, {high + 0.0:g}]" in line
    elif position or affine:
        assert "force unbounded" in line
    if model.actuator_trntype[i] == mujoco.mjtTrn.mjTRN_JOINT:
        joint = model.actuator_trnid[i, 0]
        kind = {mujoco.mjtJoint.mjJNT_SLIDE: "slide", mujoco.mjtJoint.mjJNT_HINGE: "hinge"}.get(
            mujoco.mjtJoint(model.jnt_type[joint])
        )
        if kind:
            length, force = UNIT[kind]
            units = set(re.findall(r"\] ([^ ;(]+)", line))
            assert units <= {length, force, f"{length}/s"}, (line, units)


@pytest.mark.parametrize(("name", "path"), _models(), ids=[n for n, _ in _models()])
def test_actuator_and_contact_statements_are_true_of_each_model(name, path):
    model = load_model(path) if name != "fetch" else mujoco.MjModel.from_xml_path(str(path))
    lines = actuator_lines(model)
    assert len(lines) == 1 + model.nu
    for i in range(model.nu):
        _check_actuator_line(model, i, lines[1 + i])
        assert "not a motor with a limited control" not in lines[1 + i]
    pairs = collision_pairs(model)
    assert pairs == _documented_pairs(model)
    text = "\n".join(contact_lines(model, max_pairs=len(pairs) or 1))
    geom = lambda g: mujoco.mj_id2name(model, mujoco.mjtObj.mjOBJ_GEOM, g) or (  # noqa: E731
        f"geom {g} of body {model.body(model.geom_bodyid[g]).name}"  # an unnamed one
    )
    listed = re.findall(r"`([^`]+)`–`([^`]+)`", text)
    assert listed == [(geom(a), geom(b)) for a, b in pairs]


@pytest.mark.parametrize("path", BUILT_IN, ids=[p.stem for p in BUILT_IN])
def test_a_study_is_named_only_when_the_config_declares_it(path):
    config = _config(path)
    # what the report stage is given: its slice of the config, which leaves the variants out
    for given in (config, config_slice("report", config)):
        text = " ".join(_scope_limits(given))
        assert ("sensitivity study" in text and "declares" in text) == bool(config.get("variants"))
    without = {k: v for k, v in config.items() if k != "variants"}
    for given in (without, config_slice("report", without)):
        text = " ".join(_scope_limits(given))
        assert "No sensitivity study is configured" in text
        assert "what the sensitivity study asks" not in text


def test_the_report_s_slice_changes_when_the_first_variant_comes_not_with_each_one():
    config = _config(BUILT_IN[0])
    without = {k: v for k, v in config.items() if k != "variants"}
    one = {**without, "variants": {"a": {"option": {"timestep": 0.001}}}}
    two = {**without, "variants": {**one["variants"], "b": {"option": {"timestep": 0.004}}}}
    assert config_slice("report", one) == config_slice("report", two)
    assert config_slice("report", without) != config_slice("report", one)


TASK = load_task(_config(REPO / "config" / "config.yaml")["task"], repo_root=REPO)


def _summary(success: dict[str, list[bool]], nominal: dict[str, bool]) -> dict:
    """A summary of the gantry task with these outcomes per condition ("fast" the baseline)."""
    n = len(next(iter(success.values())))
    rng = np.random.default_rng(0)
    states = {"state_id": np.arange(n)}
    for p in TASK.state_columns[1:]:
        states[p] = rng.uniform(0.0, 0.5, n)
    outcomes = {
        name: {
            "state_id": np.arange(n),
            "success": np.array(s),
            "nonfinite": np.zeros(n, bool),
            "warning": np.array([""] * n, dtype=object),
            "failure_category": np.array(["" if ok else "slipped" for ok in s], dtype=object),
        }
        for name, s in success.items()
    }
    analysis = {"n_resamples": 200, "confidence": 0.95, "seed": 1, "bands": {}, "first_k": 3}
    falsifier = {"treatment": "slow", "baseline": "fast", "statistic": "paired_difference"}
    return summarize(
        states=states,
        outcomes=outcomes,
        nominal=nominal,
        condition_parameters={name: {} for name in success},
        falsifier={**falsifier, "threshold": 0.0, "max_unhealthy_share": 0.0},
        analysis=analysis,
    )


def _results_text(summary: dict) -> str:
    return "\n".join(_results(summary, {}, list(summary["conditions"]), TASK))


@pytest.mark.parametrize(("value", "bound"), [(True, "ceiling"), (False, "floor")])
def test_a_comparison_at_its_ceiling_or_floor_is_said_to_be_one(value, bound):
    summary = _summary({"fast": [value] * 8, "slow": [value] * 8}, {"fast": True, "slow": True})
    paired = summary["paired_difference"]
    assert paired["replaces"]["low"] == paired["replaces"]["high"] == 0.0  # the bootstrap's
    _, low, high = newcombe_paired_interval(*([8, 0, 0, 0] if value else [0, 0, 0, 8]))
    assert (paired["low"], paired["high"]) == (low, high)
    text = _results_text(summary)
    assert f"The comparison is at its {bound}" in text
    assert "is degenerate there" in text
    assert ", 95% interval [+0.000, +0.000]" not in text
    assert f"valid there: **[{low:+.3f}, {high:+.3f}]**" in text
    assert "Newcombe hybrid score" in text


def test_a_comparison_with_discordant_pairs_keeps_its_interval():
    summary = _summary(
        {
            "fast": [True, False, True, False, True, True],
            "slow": [True, True, True, False] * 1 + [False, True],
        },
        {"fast": True, "slow": True},
    )
    paired = summary["paired_difference"]
    assert paired["low"] < paired["high"]
    text = _results_text(summary)
    assert f"95% interval [{paired['low']:+.3f}, {paired['high']:+.3f}]" in text
    assert "ceiling" not in text and "floor" not in text and "degenerate" not in text


def test_the_nominal_shortcut_names_every_conditions_outcome():
    summary = _summary(
        {"fast": [True, False] * 3, "slow": [True] * 6}, {"fast": False, "slow": True}
    )
    text = "\n".join(_mistakes(summary, ["fast", "slow"], TASK))
    line = next(s for s in text.splitlines() if s.startswith("- *The nominal state"))
    fast = summary["mistakes"]["nominal_state"]["conditions"]["fast"]
    slow = summary["mistakes"]["nominal_state"]["conditions"]["slow"]
    assert (
        f"fast failed (0/1, interval [{fast['wilson_low']:.3f}, {fast['wilson_high']:.3f}])" in line
    )
    assert (
        f"slow succeeded (1/1, interval [{slow['wilson_low']:.3f}, {slow['wilson_high']:.3f}])"
        in line
    )


def _three_condition_summary() -> dict:
    """fast, medium and slow (every state a success) against fast; registered with the
    falsifier's comparison alone, so medium - fast is exploratory."""
    n = 12
    success = {
        "fast": [True, False] * 6,
        "medium": [True, True, False] * 4,
        "slow": [True] * 12,
    }
    outcomes = {
        name: {
            "state_id": np.arange(n),
            "success": np.array(s),
            "nonfinite": np.zeros(n, bool),
            "warning": np.array([""] * n, dtype=object),
            "failure_category": np.array(["" if ok else "slipped" for ok in s], dtype=object),
        }
        for name, s in success.items()
    }
    analysis = {
        "n_resamples": 200,
        "confidence": 0.95,
        "seed": 1,
        "bands": {},
        "first_k": 3,
        "comparisons": {"against": "fast"},
    }
    falsifier = {"treatment": "slow", "baseline": "fast", "statistic": "paired_difference"}
    return summarize(
        states={"state_id": np.arange(n), **{p: np.zeros(n) for p in TASK.state_columns[1:]}},
        outcomes=outcomes,
        nominal={name: True for name in success},
        condition_parameters={name: {} for name in success},
        falsifier={**falsifier, "threshold": 0.0},
        analysis=analysis,
        registered={"design": {"falsifier": falsifier}, "analysis": {}},  # registered sections
    )


def test_every_planned_comparison_is_in_the_results_with_holm_and_the_exploratory_marked():
    summary = _three_condition_summary()
    text = _results_text(summary)
    assert "### Planned comparisons" in text
    for record in summary["comparisons"]:
        m = record["mcnemar"]
        assert f"p = {m['p_value']:.3g}; Holm step-down" in text
        assert f"adjusted p = {m['p_holm']:.3g}" in text
    assert "| medium - fast | secondary, **exploratory** |" in text
    assert "| slow - fast | primary (the falsifier's) |" in text


def test_the_paired_figure_has_a_panel_per_comparison_with_its_holm_p_and_no_overlap():
    from test_report import _drawn_texts, _text_problems

    from mjtrial.report.figures import figure_paired_outcomes

    summary = _three_condition_summary()
    fig = figure_paired_outcomes(summary=summary, task=TASK)
    texts = [t for t, _ in _drawn_texts(fig)]
    for record in summary["comparisons"]:
        p = record["paired_difference"]
        caption = next(t for t in texts if t.startswith(f"{p['treatment']} - {p['baseline']}:"))
        assert f"Holm p = {record['mcnemar']['p_holm']:.3g}" in caption
    assert any("(exploratory)" in t for t in texts)
    assert _text_problems(fig) == []
