"""Tests for mjtrial.benchmark.stats against independent references: closed forms written out
here, scipy.stats (which the code under test does not use), a hand-computed Holm step-down,
plain-loop reruns of the documented bootstrap draws, rliable's published test values, and
numbers computed with rliable itself, pasted as constants."""

from __future__ import annotations

import math
import statistics

import numpy as np
import pytest
from scipy import stats as sps

from mjtrial.benchmark import stats as bstats
from mjtrial.benchmark.stats import (
    DEVELOPMENT_DECISION,
    REPORTED_RESULT,
    SEEDS_FOR_DEVELOPMENT_DECISION,
    SEEDS_FOR_REPORTED_RESULT,
    aggregate_iqm,
    aggregate_mean,
    aggregate_median,
    compare_methods,
    episode_mean,
    holm,
    optimality_gap,
    performance_profile,
    performance_profile_ci,
    seed_count_label,
    seed_spread,
    stratified_bootstrap_ci,
    task_mean,
)

# A method's (training seeds x tasks) success rates, 50 evaluation episodes each.
SCORES = np.array(
    [
        [0.62, 0.98, 0.10, 0.44],
        [0.80, 0.96, 0.02, 0.58],
        [0.54, 1.00, 0.36, 0.40],
        [0.70, 0.90, 0.08, 0.96],
        [0.66, 0.94, 0.00, 0.50],
    ]
)
TAUS = np.array([0.05, 0.45, 0.65, 0.95])


def wilson(successes: int, n: int, confidence: float = 0.95) -> tuple[float, float]:
    ci = sps.binomtest(successes, n).proportion_ci(confidence_level=confidence, method="wilson")
    return ci.low, ci.high


def outcomes(successes: int, n: int) -> np.ndarray:
    return np.array([1] * successes + [0] * (n - successes))


# --------------------------------------------------------------------------------------------
# Two overall success rates
# --------------------------------------------------------------------------------------------


def test_course_example_episode_mean_and_task_mean_differ():
    """8 episodes of an easy task all succeed, 2 of a hard one all fail: 80 % and 50 %."""
    runs = {"easy": [1] * 8, "hard": [0] * 2}
    estimate, low, high = episode_mean(runs)
    assert estimate == pytest.approx(0.8)
    assert (low, high) == pytest.approx(wilson(8, 10), rel=1e-12)
    estimate, low, high = task_mean(runs)
    assert estimate == pytest.approx(0.5)
    # each task's rate is certain only to a Wilson interval: the mean's interval keeps a width
    assert low < 0.5 < high


def test_episode_mean_pools_every_episode():
    tasks = [outcomes(3, 7), outcomes(20, 20), outcomes(0, 4), outcomes(11, 30)]
    estimate, low, high = episode_mean(tasks, confidence=0.9)
    assert estimate == pytest.approx(34 / 61)
    assert (low, high) == pytest.approx(wilson(34, 61, 0.9), rel=1e-12)
    # a mapping's values are the tasks, bool outcomes count as 0/1
    named = {f"t{i}": t.astype(bool) for i, t in enumerate(tasks)}
    assert episode_mean(named, confidence=0.9) == (estimate, low, high)


@pytest.mark.parametrize(
    "counts",
    [
        [(3, 7), (20, 20), (0, 4), (11, 30)],
        [(8, 8), (0, 2)],
        [(50, 50), (49, 50), (48, 50)],
        [(5, 10), (1, 3)],
    ],
)
def test_task_mean_is_mover_over_wilson_intervals(counts):
    """Zou, Huang & Zhang (2009): L -/+ sqrt(sum of squared distances to the Wilson bounds)/T."""
    rates = [s / n for s, n in counts]
    bounds = [wilson(s, n) for s, n in counts]
    mean = sum(rates) / len(rates)
    below = math.sqrt(sum((p - lo) ** 2 for p, (lo, _) in zip(rates, bounds, strict=True)))
    above = math.sqrt(sum((hi - p) ** 2 for p, (_, hi) in zip(rates, bounds, strict=True)))
    estimate, low, high = task_mean([outcomes(s, n) for s, n in counts])
    assert estimate == pytest.approx(mean, rel=1e-12)
    assert low == pytest.approx(mean - below / len(counts), rel=1e-12)
    assert high == pytest.approx(mean + above / len(counts), rel=1e-12)


def test_task_mean_of_one_task_is_its_wilson_interval_and_bounds_are_exact():
    estimate, low, high = task_mean([outcomes(7, 19)], confidence=0.8)
    assert (estimate, low, high) == pytest.approx((7 / 19, *wilson(7, 19, 0.8)), rel=1e-12)
    assert task_mean([outcomes(0, 5), outcomes(0, 9)])[1] == 0.0
    estimate, low, high = task_mean([outcomes(5, 5), outcomes(9, 9)])
    assert (estimate, high) == (1.0, 1.0)
    assert low < 1.0


def test_unequal_episode_counts_weigh_differently_in_the_two_means():
    tasks = [outcomes(90, 100), outcomes(1, 10)]
    assert episode_mean(tasks)[0] == pytest.approx(91 / 110)
    assert task_mean(tasks)[0] == pytest.approx((0.9 + 0.1) / 2)


@pytest.mark.parametrize(
    "bad, message",
    [
        ([], "at least one task"),
        ([[1, 0, 2]], "0/1"),
        ([[]], "at least one value"),
        (np.ones((2, 3)), "sequence or mapping"),
    ],
)
def test_outcomes_are_checked(bad, message):
    for function in (episode_mean, task_mean):
        with pytest.raises(ValueError, match=message):
            function(bad)


# --------------------------------------------------------------------------------------------
# rliable's aggregates and their stratified bootstrap
# --------------------------------------------------------------------------------------------


def test_aggregates_match_rliables_published_test_values():
    # rliable tests/rliable/metrics_test.py (num_runs x num_tasks)
    x = np.array([[1, 2], [2, 2], [1, 1], [2, 1]])
    y = np.array([[1, 1], [2, 2], [3, 3]])
    for aggregate in (aggregate_median, aggregate_mean, aggregate_iqm):
        assert aggregate(x) == 1.5
        assert aggregate(y) == 2


def test_aggregates_match_their_definitions():
    task_means = [statistics.fmean(SCORES[:, j]) for j in range(SCORES.shape[1])]
    assert aggregate_iqm(SCORES) == pytest.approx(sps.trim_mean(SCORES.ravel(), 0.25))
    assert aggregate_iqm(SCORES) == pytest.approx(0.614)
    assert aggregate_median(SCORES) == pytest.approx(statistics.median(task_means))
    assert aggregate_mean(SCORES) == pytest.approx(statistics.fmean(task_means))
    shortfall = [1.0 - min(s, 1.0) for s in SCORES.ravel()]
    assert optimality_gap(SCORES) == pytest.approx(statistics.fmean(shortfall))
    clipped = [0.5 - min(s, 0.5) for s in SCORES.ravel()]
    assert optimality_gap(SCORES, gamma=0.5) == pytest.approx(statistics.fmean(clipped))


def naive_stratified_bootstrap(scores, statistic, n_resamples, seed, confidence=0.95):
    """The documented draws, one resample and one cell at a time."""
    rng = np.random.default_rng(seed)
    runs, tasks = scores.shape
    boot = []
    for _ in range(n_resamples):
        idx = rng.integers(0, runs, size=(runs, tasks))
        resample = [[scores[idx[i, j], j] for j in range(tasks)] for i in range(runs)]
        boot.append(statistic(np.array(resample)))
    alpha = 1 - confidence
    return np.percentile(np.array(boot), [100 * alpha / 2, 100 * (1 - alpha / 2)], axis=0)


@pytest.mark.parametrize(
    "ours, reference",
    [
        (aggregate_iqm, lambda s: sps.trim_mean(s.ravel(), 0.25)),
        (aggregate_median, lambda s: statistics.median(s.mean(axis=0))),
        (aggregate_mean, lambda s: statistics.fmean(s.ravel())),
        (optimality_gap, lambda s: 1 - statistics.fmean(np.minimum(s, 1).ravel())),
    ],
)
def test_stratified_bootstrap_reruns_as_a_plain_loop(ours, reference):
    estimate, low, high = stratified_bootstrap_ci(
        SCORES, ours, n_resamples=400, confidence=0.9, seed=11
    )
    assert estimate == pytest.approx(reference(SCORES))
    expected = naive_stratified_bootstrap(SCORES, reference, 400, seed=11, confidence=0.9)
    assert (low, high) == pytest.approx(tuple(expected), rel=1e-12)


def test_stratified_bootstrap_does_not_depend_on_the_block_size(monkeypatch):
    whole = stratified_bootstrap_ci(SCORES, n_resamples=301, seed=3)
    monkeypatch.setattr(bstats, "_MAX_BLOCK_ELEMENTS", 7 * SCORES.size)  # 7 resamples a block
    assert stratified_bootstrap_ci(SCORES, n_resamples=301, seed=3) == whole


def test_bootstrap_resamples_runs_within_each_task_only():
    """A task whose seeds agree adds no spread: the resamples leave every such column as it is.

    Resampling all the cells together would mix the tasks and give a wide interval here."""
    scores = np.tile([0.1, 0.4, 0.9], (5, 1))
    for statistic in (aggregate_iqm, aggregate_median, aggregate_mean, optimality_gap):
        estimate, low, high = stratified_bootstrap_ci(scores, statistic, n_resamples=500, seed=0)
        assert low == pytest.approx(estimate) and high == pytest.approx(estimate)


def test_interval_matches_rliable_on_the_same_scores():
    """rliable 1.2.0 (arch 7.2.0, numpy 2.4.6, pandas 2.3.3), computed with::

        np.random.seed(0)
        rly.get_interval_estimates({"m": SCORES}, lambda x: np.array([metrics.aggregate_iqm(x),
            metrics.aggregate_median(x), metrics.aggregate_mean(x),
            metrics.aggregate_optimality_gap(x)]))  # percentile, reps=50000, 95 %

    rliable draws with numpy's global state, so only Monte Carlo agreement is possible: the
    bounds sit on a grid of 0.002 and, over seeds 0-4 of either code, moved by one step at
    most. A basic (not percentile) interval is 0.02 off, resampling all cells together 0.1.
    """
    rliable_points = [0.614, 0.62, 0.577, 0.423]
    rliable_low = [0.536, 0.53795, 0.526, 0.362]
    rliable_high = [0.718, 0.726, 0.638, 0.474]
    for k, statistic in enumerate(
        (aggregate_iqm, aggregate_median, aggregate_mean, optimality_gap)
    ):
        estimate, low, high = stratified_bootstrap_ci(SCORES, statistic, seed=0)
        assert estimate == pytest.approx(rliable_points[k], abs=1e-12)
        assert low == pytest.approx(rliable_low[k], abs=0.0025)
        assert high == pytest.approx(rliable_high[k], abs=0.0025)


def test_interval_contains_the_estimate_as_rliables_library_test_asserts():
    # rliable tests/library_test.py: 5 runs x 16 tasks, arange, and its flip over runs
    x = np.arange(80.0).reshape(5, 16)
    for scores in (x, np.flip(x, axis=0)):
        for statistic in (aggregate_iqm, aggregate_mean, aggregate_median, optimality_gap):
            estimate, low, high = stratified_bootstrap_ci(
                scores, statistic, n_resamples=2000, seed=1
            )
            assert low < estimate < high


# --------------------------------------------------------------------------------------------
# Performance profiles
# --------------------------------------------------------------------------------------------


def test_performance_profile_counts_scores_strictly_above_tau():
    cells = SCORES.ravel().tolist()
    expected = [sum(s > tau for s in cells) / len(cells) for tau in TAUS]
    assert performance_profile(SCORES, TAUS) == pytest.approx(expected)
    # strictly above: a score equal to tau does not count
    assert performance_profile(np.array([[0.5, 0.5], [0.2, 1.0]]), [0.5]).tolist() == [0.25]


def test_performance_profile_ci_reruns_as_a_plain_loop():
    def profile(s):
        cells = s.ravel().tolist()
        return [sum(c > tau for c in cells) / len(cells) for tau in TAUS]

    profile_, low, high = performance_profile_ci(SCORES, TAUS, n_resamples=300, seed=5)
    expected_low, expected_high = naive_stratified_bootstrap(SCORES, profile, 300, seed=5)
    assert profile_ == pytest.approx(profile(SCORES))
    assert low == pytest.approx(expected_low, rel=1e-12)
    assert high == pytest.approx(expected_high, rel=1e-12)


def test_performance_profile_ci_matches_rliable():
    """rliable 1.2.0, computed with::

        np.random.seed(0)
        rly.create_performance_profile({"m": SCORES}, TAUS, reps=50000)

    (the same bounds for seeds 0, 1 and 2; they sit on a grid of 0.05)."""
    profile, low, high = performance_profile_ci(SCORES, TAUS, n_resamples=50_000, seed=0)
    assert profile == pytest.approx([0.9, 0.65, 0.45, 0.2], abs=1e-12)
    assert low == pytest.approx([0.8, 0.55, 0.3, 0.05], abs=1e-9)
    assert high == pytest.approx([1.0, 0.75, 0.6, 0.35], abs=1e-9)


@pytest.mark.parametrize(
    "scores, message",
    [
        (np.ones(4), r"\(runs, tasks\) matrix"),
        (np.ones((0, 3)), "at least one run"),
        (np.array([[0.5, np.nan]]), "finite"),
    ],
)
def test_scores_are_checked(scores, message):
    with pytest.raises(ValueError, match=message):
        stratified_bootstrap_ci(scores, seed=0)
    with pytest.raises(ValueError, match=message):
        performance_profile_ci(scores, TAUS, seed=0)


def test_bootstrap_arguments_are_checked():
    with pytest.raises(ValueError, match="n_resamples must be >= 1"):
        stratified_bootstrap_ci(SCORES, n_resamples=0, seed=0)
    with pytest.raises(ValueError, match="seed must be >= 0"):
        stratified_bootstrap_ci(SCORES, seed=-1)
    with pytest.raises(ValueError, match="confidence must be strictly between 0 and 1"):
        performance_profile_ci(SCORES, TAUS, confidence=1.0, seed=0)
    with pytest.raises(ValueError, match="statistic must return a scalar"):
        stratified_bootstrap_ci(SCORES, lambda s: performance_profile(s, TAUS), seed=0)


# --------------------------------------------------------------------------------------------
# Paired differences, Holm-adjusted
# --------------------------------------------------------------------------------------------


def naive_holm(p_values):
    """Holm's step-down written out: the i-th smallest times (m - i), running max, cap 1."""
    m = len(p_values)
    order = sorted(range(m), key=lambda i: p_values[i])
    adjusted, running = [0.0] * m, 0.0
    for rank, i in enumerate(order):
        running = max(running, (m - rank) * p_values[i])
        adjusted[i] = min(1.0, running)
    return adjusted


def test_holm_by_hand():
    # sorted: 0.005 x 4 = 0.02, 0.01 x 3 = 0.03, 0.03 x 2 = 0.06, 0.04 x 1 -> max(0.04, 0.06)
    assert holm([0.01, 0.04, 0.03, 0.005]) == pytest.approx([0.03, 0.06, 0.06, 0.02])
    assert holm([0.5, 0.4]) == pytest.approx([0.8, 0.8])
    assert holm([0.9, 0.2]) == pytest.approx([0.9, 0.4])
    p = np.random.default_rng(4).uniform(0, 0.2, size=9)
    assert holm(p) == pytest.approx(naive_holm(p.tolist()), rel=1e-12)


def test_holm_checks_its_p_values():
    with pytest.raises(ValueError, match=r"p_values must lie in \[0, 1\]"):
        holm([0.2, 1.5])
    with pytest.raises(ValueError, match="p_values must contain at least one value"):
        holm([])


def paired(only_a, only_b, both, neither, seed=0):
    a = [1] * only_a + [0] * only_b + [1] * both + [0] * neither
    b = [0] * only_a + [1] * only_b + [1] * both + [0] * neither
    perm = np.random.default_rng(seed).permutation(len(a))
    return np.array(a)[perm], np.array(b)[perm]


def test_compare_methods_mcnemar_per_task_then_holm():
    counts = {
        "reach": (9, 1, 20, 5),
        "lift": (6, 2, 10, 2),
        "push": (3, 3, 4, 0),
        "hold": (8, 0, 0, 1),
    }
    pairs = {task: paired(*c, seed=i) for i, (task, c) in enumerate(counts.items())}
    rows = compare_methods({t: p[0] for t, p in pairs.items()}, {t: p[1] for t, p in pairs.items()})
    assert [r.task for r in rows] == list(counts)
    raw = [sps.binomtest(c[0], c[0] + c[1], 0.5).pvalue for c in counts.values()]
    adjusted = naive_holm(raw)
    for row, c, p, q in zip(rows, counts.values(), raw, adjusted, strict=True):
        only_a, only_b, both, neither = c
        n = sum(c)
        assert (row.only_a, row.only_b, row.n_pairs) == (only_a, only_b, n)
        assert row.rate_a == pytest.approx((only_a + both) / n)
        assert row.rate_b == pytest.approx((only_b + both) / n)
        assert row.difference == pytest.approx((only_a - only_b) / n)
        assert row.p_value == pytest.approx(p, rel=1e-12)
        assert row.p_holm == pytest.approx(q, rel=1e-12)
        assert row.significant == (q <= 0.05)
    # 8 against 0 alone gives p = 2/256; Holm multiplies the smallest of four by 4
    assert rows[3].p_value == pytest.approx(2 / 2**8)
    assert rows[3].p_holm == pytest.approx(4 * 2 / 2**8)
    assert rows[3].significant and not rows[1].significant


def test_compare_methods_checks_its_tasks():
    a, b = paired(2, 1, 3, 1)
    with pytest.raises(ValueError, match=r"same tasks; only in a: \['x'\]"):
        compare_methods({"x": a, "y": a}, {"y": b})
    with pytest.raises(ValueError, match="task 'y': a and b must have the same length"):
        compare_methods({"y": a}, {"y": b[:-1]})
    with pytest.raises(ValueError, match="at least one task"):
        compare_methods({}, {})


# --------------------------------------------------------------------------------------------
# Training seeds
# --------------------------------------------------------------------------------------------


def test_seed_spread_is_min_median_max():
    rates = [0.62, 0.80, 0.54, 0.70, 0.66, 0.98]
    spread = seed_spread(rates)
    assert spread.n_seeds == 6
    assert spread.minimum == 0.54
    assert spread.median == pytest.approx(statistics.median(rates))  # (0.66 + 0.70) / 2
    assert spread.median == pytest.approx(0.68)
    assert spread.maximum == 0.98
    with pytest.raises(ValueError, match="rates must contain at least one value"):
        seed_spread([])


def test_seed_count_rules():
    assert (SEEDS_FOR_DEVELOPMENT_DECISION, SEEDS_FOR_REPORTED_RESULT) == (3, 5)
    assert [seed_count_label(n) for n in (3, 4, 5, 10, 12)] == [
        DEVELOPMENT_DECISION,
        DEVELOPMENT_DECISION,
        REPORTED_RESULT,
        REPORTED_RESULT,
        REPORTED_RESULT,
    ]
    assert seed_count_label(5, require_reported=True) == REPORTED_RESULT
    for n in (0, 1, 2):
        with pytest.raises(ValueError, match=f"n_seeds must be >= 3 .*got {n}"):
            seed_count_label(n)
        with pytest.raises(
            ValueError, match=f"n_seeds must be >= 5 for a reported result.*got {n}"
        ):
            seed_count_label(n, require_reported=True)
    with pytest.raises(ValueError, match="n_seeds must be >= 5 for a reported result"):
        seed_count_label(4, require_reported=True)
    with pytest.raises(ValueError, match="n_seeds must be an integer"):
        seed_count_label(4.0)
