"""The planned comparisons read from the config, and which a registration did not plan."""

from __future__ import annotations

from mjtrial.stats.comparisons import Comparison, exploratory, planned_comparisons

FALSIFIER = {"treatment": "slow", "baseline": "fast"}
CONDITIONS = ["fast", "medium", "slow"]


def pairs(analysis, falsifier=FALSIFIER, conditions=CONDITIONS):
    return [
        (c.treatment, c.baseline, c.primary)
        for c in planned_comparisons(analysis, falsifier, conditions)
    ]


def test_default_is_the_falsifier_pair_alone():
    assert pairs({}) == [("slow", "fast", True)]


def test_against_pairs_every_other_condition_with_the_baseline_falsifier_first():
    assert pairs({"comparisons": {"against": "fast"}}) == [
        ("slow", "fast", True),
        ("medium", "fast", False),
    ]


def test_against_the_falsifier_treatment_counts_the_falsifier_pair_once():
    assert pairs({"comparisons": {"against": "slow"}}) == [
        ("slow", "fast", True),
        ("medium", "slow", False),
    ]


def test_listed_pairs_keep_their_order_and_the_falsifier_is_added_first():
    listed = {"comparisons": [["medium", "fast"], ["slow", "medium"]]}
    assert pairs(listed) == [
        ("slow", "fast", True),
        ("medium", "fast", False),
        ("slow", "medium", False),
    ]
    with_it = {"comparisons": [["medium", "fast"], ["slow", "fast"]]}
    assert pairs(with_it) == [("slow", "fast", True), ("medium", "fast", False)]


def test_nothing_is_exploratory_without_a_registration():
    plan = planned_comparisons({"comparisons": {"against": "fast"}}, FALSIFIER, CONDITIONS)
    assert exploratory(plan, None) == [False, False]


def test_a_comparison_the_registration_did_not_plan_is_exploratory():
    plan = planned_comparisons(
        {"comparisons": [["medium", "fast"], ["slow", "medium"]]}, FALSIFIER, CONDITIONS
    )
    registered = {  # the config's sections as registration.json holds them
        "design": {"falsifier": dict(FALSIFIER)},
        "conditions": {"fast": {}, "medium": {}, "slow": {}},
        "analysis": {"comparisons": {"against": "fast"}},
    }
    assert exploratory(plan, registered) == [False, False, True]
    # registered with no comparisons: the falsifier's alone
    registered["analysis"] = {}
    assert exploratory(plan, registered) == [False, True, True]


def test_a_reversed_registered_pair_is_the_same_comparison():
    plan = [Comparison("medium", "fast")]
    registered = {"analysis": {"comparisons": [["fast", "medium"]]}}
    assert exploratory(plan, registered) == [False]
