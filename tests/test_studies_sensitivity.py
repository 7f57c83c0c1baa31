"""The sensitivity record on hand-built rollout tables, against closed forms."""

from __future__ import annotations

import math
from statistics import NormalDist

import numpy as np
import pytest
from conftest import REPO_ROOT

from mjtrial import stats
from mjtrial.stages.studies import study_report_text
from mjtrial.studies.sensitivity import NOMINAL, summarize_sensitivity, variant_record

pytestmark = pytest.mark.end_to_end

FALSIFIER = {
    "treatment": "slow",
    "baseline": "fast",
    "statistic": "paired_difference",
    "threshold": 0.0,
}
ANALYSIS = {"confidence": 0.95, "n_resamples": 200, "seed": 3}


def table(success, *, warning=None, nonfinite=None, category=None, ids=None):
    success = np.asarray(success, dtype=bool)
    n = success.size
    return {
        "state_id": np.arange(n) if ids is None else np.asarray(ids),
        "success": success,
        "nonfinite": np.zeros(n, bool) if nonfinite is None else np.asarray(nonfinite),
        "warning": np.array([""] * n if warning is None else warning, dtype=object),
        "failure_category": np.array(
            [None if s else "slipped during the lift" for s in success]
            if category is None
            else category,
            dtype=object,
        ),
    }


def wilson(k, n, confidence=0.95):
    z = NormalDist().inv_cdf(0.5 + confidence / 2)
    p = k / n
    centre = (p + z * z / (2 * n)) / (1 + z * z / n)
    half = z / (1 + z * z / n) * math.sqrt(p * (1 - p) / n + z * z / (4 * n * n))
    return centre - half, centre + half


def record(slow, fast, **kwargs):
    return variant_record(
        {"fast": fast, "slow": slow},
        overrides={"option": {"timestep": 0.001}},
        model_sha256="ab" * 32,
        falsifier=FALSIFIER,
        analysis=ANALYSIS,
        **kwargs,
    )


def test_rates_wilson_and_a_difference_every_resample_agrees_on():
    # Every pair differs by +1 or every pair by 0: each bootstrap mean equals the estimate.
    slow = table([1] * 8 + [0] * 2)
    fast = table([0] * 8 + [0] * 2)
    rec = record(slow, fast)
    assert rec["conditions"]["slow"]["successes"] == 8
    assert rec["conditions"]["slow"]["rate"] == 0.8
    assert rec["conditions"]["slow"]["wilson_low"] == pytest.approx(wilson(8, 10)[0], abs=1e-12)
    assert rec["conditions"]["slow"]["wilson_high"] == pytest.approx(wilson(8, 10)[1], abs=1e-12)
    assert rec["conditions"]["fast"]["wilson_low"] == 0.0
    # differences: eight +1, two 0; a resample's mean lies in [0, 1]; estimate 0.8
    assert rec["paired_difference"]["estimate"] == pytest.approx(0.8)
    assert 0.0 <= rec["paired_difference"]["low"] <= 0.8 <= rec["paired_difference"]["high"]
    assert rec["verdict"] == "survives" and rec["unhealthy"] == 0
    assert rec["model_sha256"] == "ab" * 32
    assert rec["overrides"] == {"option": {"timestep": 0.001}}


def test_all_differences_positive_survive_and_none_refute():
    ones = table([1] * 6)
    zeros = table([0] * 6)
    up = record(ones, zeros)
    # Newcombe's interval of six pairs all to the treatment, as the main analysis gives it
    interval = (1.0, *stats.newcombe_paired_interval(0, 6, 0, 0)[1:])
    paired = up["paired_difference"]
    assert (paired["estimate"], paired["low"], paired["high"]) == interval
    assert up["verdict"] == "survives"  # exact McNemar p = 2 / 2^6 = 0.031: one-sided 0.016
    same = record(ones, ones)
    assert same["paired_difference"]["low"] < 0.0 < same["paired_difference"]["high"]
    assert same["verdict"] == "refuted"  # no discordant pair: no difference shown


def test_pairs_are_aligned_by_state_id():
    slow = table([1, 1, 0, 0], ids=[3, 2, 1, 0])  # states 3, 2 succeed
    fast = table([0, 0, 1, 1], ids=[0, 1, 2, 3])  # states 2, 3 succeed
    assert record(slow, fast)["paired_difference"]["estimate"] == 0.0
    with pytest.raises(ValueError, match="state ids differ"):
        record(table([1, 1]), table([0, 0], ids=[0, 5]))


@pytest.mark.parametrize(
    "kind",
    [
        {"warning": ["", "mjWARN_BADQACC", "", "", "", ""]},
        {"nonfinite": [False, True, False, False, False, False]},
        {"category": [None, "simulation unhealthy", None, None, None, None]},
    ],
)
def test_an_unhealthy_variant_is_invalid_never_refuted(kind):
    # Without the unhealthy episode this would be refuted (no difference at all).
    slow = table([1] * 6, **kind)
    fast = table([1] * 6)
    rec = record(slow, fast)
    assert rec["verdict"] == "invalid"
    assert rec["unhealthy"] == 1
    assert rec["conditions"]["slow"]["unhealthy"] == 1
    assert rec["reason"].startswith("1 of 12 episodes unhealthy")


def test_summary_counts_verdicts_without_the_nominal_row():
    good, bad = table([1] * 6), table([0] * 6)
    sick = table([1] * 6, warning=["mjWARN_BADQACC"] + [""] * 5)

    def variant(slow, fast):
        return {"tables": {"fast": fast, "slow": slow}, "overrides": {}, "model_sha256": "0"}

    summary = summarize_sensitivity(
        {
            NOMINAL: variant(good, bad),
            "a": variant(good, bad),
            "b": variant(good, good),
            "c": variant(sick, bad),
        },
        falsifier=FALSIFIER,
        analysis=ANALYSIS,
    )
    assert list(summary["variants"]) == [NOMINAL, "a", "b", "c"]
    assert summary["n_variants"] == 3
    assert summary["verdicts"] == {"survives": 1, "refuted": 1, "invalid": 1}
    assert summary["survives_in"] == 1


def test_the_study_reads_every_condition_under_every_variant(tmp_path):
    """Snakemake's own plan: with a third condition, its variant tables are the sensitivity
    job's inputs (a condition that collapses under a variant is counted, not left out)."""
    import re

    from conftest import copy_workflow, edit_config, run_snakemake

    from mjtrial.design.conditions import sensitivity_conditions

    workdir = copy_workflow(tmp_path)

    def three(config):
        config["conditions"]["medium"] = {"lift_time": 0.5}
        config["variants"] = {"rk4": {"option": {"integrator": "RK4"}}}

    edit_config(workdir, three)
    out = run_snakemake(workdir, "-n", "--forceall", "sensitivity").stdout
    block = re.search(r"^(?:local)?rule study_sensitivity:(.*?)(?:\n\n|\Z)", out, re.M | re.S)[1]
    inputs = re.search(r"^    input: (.*)$", block, re.M)[1].split(", ")
    for condition in ("slow", "fast", "medium"):
        assert f"results/research_mode/variants/rk4/rollouts/{condition}.parquet" in inputs
        assert f"results/research_mode/rollouts/{condition}.parquet" in inputs
    config = {
        "design": {"falsifier": {"treatment": "b", "baseline": "c"}},
        "conditions": {"a": {}, "b": {}, "c": {}},
    }
    assert sensitivity_conditions(config) == ["b", "c", "a"]


def test_the_sensitivity_report_says_a_variants_geom_edit_in_contact_terms(tmp_path):
    """The gantry's pads alone at sliding friction 0.6 (the built-in `friction_low` lowers the
    cube's too, for this reason): the cube is at 0.8, so the pad-cube contacts keep 0.8 (MuJoCo
    takes the larger of the two); the pads' contacts with the floor (0.6) and with each other
    fall from 0.8 to 0.6."""
    good, bad = table([1] * 6), table([0] * 6)
    low = {"friction": [0.6, 0.003, 0.0001]}

    def variant(overrides):
        return {"tables": {"fast": bad, "slow": good}, "overrides": overrides, "model_sha256": "0"}

    summary = summarize_sensitivity(
        {
            NOMINAL: variant({}),
            "friction_low": variant({"geom": {"left_pad": low, "right_pad": low}}),
        },
        falsifier=FALSIFIER,
        analysis=ANALYSIS,
    )
    text = study_report_text(
        "sensitivity",
        summary,
        report=tmp_path / "report_sensitivity.md",
        figures_dir=tmp_path / "figures",
        model_file=REPO_ROOT / "models" / "gantry_gripper" / "scene.xml",
    )
    assert (
        "  - in its contacts: `left_pad` friction 0.8 0.003 0.0001 -> 0.6 0.003 0.0001; its "
        "contacts with `floor` (friction 0.8 0.005 0.0001 -> 0.6 0.005 0.0001), `right_pad` "
        "(friction 0.8 0.003 0.0001 -> 0.6 0.003 0.0001) change; its contacts with `cube` keep "
        "friction 0.8 0.003 0.0001"
    ) in text
