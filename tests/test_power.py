"""Power before the run (mjtrial.stats.power) against independent references: the exact power by
enumerating every paired table with scipy's binomial test, and a Monte Carlo simulation of
paired outcomes with numpy."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.stats import binomtest, multinomial

from mjtrial import stats
from mjtrial.stats import power


def enumerated_power(pairs: int, delta: float, discordant: float, alpha: float) -> float:
    """P(reject) summed over every (only treatment, only baseline, concordant) table of
    `pairs` pairs, each tested with scipy's exact binomial test."""
    p_t = (discordant + delta) / 2
    p_b = (discordant - delta) / 2
    total = 0.0
    for t in range(pairs + 1):
        for b in range(pairs + 1 - t):
            if t + b == 0:
                continue
            if binomtest(t, t + b, 0.5).pvalue <= alpha:
                total += multinomial.pmf([t, b, pairs - t - b], pairs, [p_t, p_b, 1 - p_t - p_b])
    return total


@pytest.mark.parametrize(
    ("pairs", "delta", "discordant"), [(20, 0.3, 0.5), (30, 0.15, 0.3), (25, 0.0, 0.4)]
)
def test_exact_power_equals_enumeration_with_scipys_binomial_test(pairs, delta, discordant):
    got = power.mcnemar_power(pairs, delta=delta, discordant=discordant, alpha=0.05)
    want = enumerated_power(pairs, delta, discordant, 0.05)
    assert got == pytest.approx(want, abs=1e-10)
    if delta == 0.0:  # the exact test keeps its level
        assert got <= 0.05


def simulated_power(pairs, delta, discordant, alpha, *, runs=20_000, seed=11) -> float:
    """The share of `runs` simulated experiments (numpy draws of each pair's outcome) whose
    McNemar exact test (`stats.mcnemar`) rejects."""
    rng = np.random.default_rng(seed)
    probs = [(discordant + delta) / 2, (discordant - delta) / 2, 1 - discordant]
    counts = rng.multinomial(pairs, probs, size=runs)
    rejected = 0
    cache: dict[tuple[int, int], bool] = {}
    for t, b, _ in counts:
        key = (int(t), int(b))
        if key not in cache:
            treatment = np.r_[np.ones(t), np.zeros(b)]
            cache[key] = stats.mcnemar(treatment, 1 - treatment).p_value <= alpha
        rejected += cache[key]
    return rejected / runs


def test_power_at_the_gantrys_n_agrees_with_a_simulation():
    # N = 200, 30 % discordant, a difference of 0.1: about 0.70. 20,000 runs give a standard
    # error of 0.0032; 0.015 is 4.6 of them. The normal approximation (Connor) planned for
    # 0.80 at N = 234, so this power is not that approximation's.
    got = power.mcnemar_power(200, delta=0.1, discordant=0.3, alpha=0.05)
    want = simulated_power(200, 0.1, 0.3, 0.05)
    assert abs(got - want) < 0.015
    assert 0.65 < got < 0.75


def test_minimum_detectable_difference_is_where_the_power_crosses_80_percent():
    mdd = power.detectable_difference(200, discordant=0.3, alpha=0.05)
    assert mdd == pytest.approx(0.1113, abs=2e-4)
    assert simulated_power(200, mdd, 0.3, 0.05) == pytest.approx(0.8, abs=0.015)
    assert simulated_power(200, mdd - 0.02, 0.3, 0.05) < 0.75


def test_pairs_for_a_target_difference_are_the_smallest_with_the_power():
    n = power.pairs_needed(0.1, discordant=0.3, alpha=0.05)
    assert power.mcnemar_power(n, delta=0.1, discordant=0.3, alpha=0.05) >= 0.8
    assert power.mcnemar_power(n - 1, delta=0.1, discordant=0.3, alpha=0.05) < 0.8
    # the exact test needs more pairs than the normal approximation promises
    assert n > stats.mcnemar_pairs_needed(0.1, 0.3)


def test_nothing_is_detectable_with_too_few_pairs():
    assert power.detectable_difference(5, discordant=0.5, alpha=0.05) is None
    plan = power.power_plan(pairs=5, alpha=0.05, discordant=0.5, source="assumed")
    assert "none up to the discordant share" in "\n".join(power.plan_lines(plan.record()))


def test_a_pilot_without_discordance_is_a_clear_error():
    with pytest.raises(ValueError, match="discordant share 0: expected in"):
        power.power_plan(pairs=50, alpha=0.05, discordant=0.0, source="pilot")
