"""The stopping rule's test (mjtrial.stats.sequential): the e-value against the mixture integral
computed another way, its martingale property under the null, the error rate over simulated
null experiments, and the record of looks; the config's stopping section checked in one line."""

from __future__ import annotations

import copy
import math

import numpy as np
import pytest
import yaml
from conftest import REPO_ROOT
from scipy import integrate
from scipy.special import betainc, betaln

from mjtrial.config import ConfigError, check_config
from mjtrial.stats import sequential

SOURCE = "config/config.yaml"
BASE = yaml.safe_load((REPO_ROOT / SOURCE).read_text())
RULE = {"rule": "mixture_sprt", "alpha": 0.025, "look_every": 20}


def mixture_by_quadrature(k: int, d: int) -> float:
    """The one-sided mixture likelihood ratio, integrated numerically: uniform prior on
    p in [1/2, 1] (density 2), the likelihood of k wins in d pairs against p = 1/2."""
    value, _ = integrate.quad(
        lambda p: 2.0 * p**k * (1 - p) ** (d - k) / 0.5**d, 0.5, 1.0, epsabs=0, epsrel=1e-12
    )
    return value


def mixture_by_betaln(k: int, d: int) -> float:
    """The same integral as a Beta-binomial closed form: 2^(d+1) B(k+1, d-k+1) times the
    upper tail of Beta(k+1, d-k+1) above 1/2."""
    upper = 1.0 - betainc(k + 1, d - k + 1, 0.5)
    return 2.0 ** (d + 1) * math.exp(betaln(k + 1, d - k + 1)) * upper


@pytest.mark.parametrize(("k", "d"), [(0, 0), (0, 1), (1, 1), (7, 7), (6, 6), (3, 10), (9, 12)])
def test_e_value_is_the_mixture_likelihood_ratio(k, d):
    e = sequential.e_value(k, d)
    assert e == pytest.approx(mixture_by_quadrature(k, d), rel=1e-9)
    assert e == pytest.approx(mixture_by_betaln(k, d), rel=1e-12)


def test_e_value_at_many_pairs_matches_the_closed_form():
    # far from the prior's mass the tail is small: betainc's complement loses nothing here
    for k, d in [(50, 80), (120, 200), (300, 400)]:
        assert sequential.e_value(k, d) == pytest.approx(mixture_by_betaln(k, d), rel=1e-9)


def test_the_e_process_is_a_martingale_under_the_null():
    # E[E_(d+1) | first d pairs] = E_d when each pair is a win with probability 1/2
    for d in range(0, 30):
        for k in range(0, d + 1):
            step = (sequential.e_value(k + 1, d + 1) + sequential.e_value(k, d + 1)) / 2
            assert step == pytest.approx(sequential.e_value(k, d), rel=1e-10)


def test_e_values_along_a_sequence_are_each_prefix_e_value():
    wins = [1, 1, 0, 1, 1, 1, 0, 1]
    along = sequential.e_values(wins)
    expected = [sequential.e_value(sum(wins[: i + 1]), i + 1) for i in range(len(wins))]
    np.testing.assert_allclose(along, expected, rtol=1e-12)


def test_discordant_wins_keeps_the_discordant_pairs_in_order():
    a = np.array([1, 1, 0, 0, 1, 0], dtype=bool)
    b = np.array([1, 0, 1, 0, 0, 0], dtype=bool)
    np.testing.assert_array_equal(sequential.discordant_wins(a, b), [1, 0, 1])
    with pytest.raises(ValueError, match=r"\(n_pairs,\)"):
        sequential.discordant_wins(a, b[:3])


def simulate_rejections(
    rng: np.random.Generator,
    *,
    n_experiments: int,
    discordance: float,
    win: float,
    max_n: int,
    block: int,
    alpha: float,
) -> np.ndarray:
    """Whether each simulated paired experiment's e-value reached its threshold (calibrated
    to max_n) at a look: each
    pair discordant with probability `discordance`, won by the treatment with `win`."""
    discordant = rng.random((n_experiments, max_n)) < discordance
    wins = discordant & (rng.random((n_experiments, max_n)) < win)
    looks = np.arange(block, max_n + 1, block) - 1
    d = np.cumsum(discordant, axis=1)[:, looks]
    k = np.cumsum(wins, axis=1)[:, looks]
    threshold = sequential.calibrated_threshold(max_n, alpha)["threshold"]
    return (sequential.log_e_value(k, d) >= math.log(threshold)).any(axis=1)


@pytest.mark.parametrize("discordance", [0.05, 0.2, 0.5])
def test_the_error_rate_under_the_null_is_at_most_alpha(discordance):
    alpha, n = 0.05, 2000
    rng = np.random.default_rng(20261127)
    rejected = simulate_rejections(
        rng, n_experiments=n, discordance=discordance, win=0.5, max_n=200, block=10, alpha=alpha
    )
    rate = rejected.mean()
    assert rate <= alpha + 3 * math.sqrt(alpha * (1 - alpha) / n)


def test_a_real_difference_is_found():
    # the same simulation is not vacuous: 40 % discordance, 80 % of it to the treatment
    rng = np.random.default_rng(7)
    rejected = simulate_rejections(
        rng, n_experiments=500, discordance=0.4, win=0.8, max_n=200, block=10, alpha=0.05
    )
    assert rejected.mean() > 0.95


def stopping(block: int, max_n: int, alpha: float = 0.05) -> dict:
    return {"rule": "mixture_sprt", "alpha": alpha, "look_every": block, "max_n": max_n}


def test_the_record_stops_at_the_first_look_that_reaches_the_threshold():
    # N = 100 at alpha 0.05: the calibrated threshold is 11.66, so 6 treatment-only pairs
    # (e = (2^7 - 1)/7 = 18.1) stop the run, and 5 (e = 10.5) do not
    a = np.array([1] * 5 + [0] * 5 + [1] + [0] * 9, dtype=bool)
    b = np.zeros(20, dtype=bool)
    record = sequential.stopping_record(a, b, stopping=stopping(10, 100))
    assert record["threshold"] == pytest.approx(11.66, abs=0.01)
    assert [look["n"] for look in record["looks"]] == [10, 20]
    assert [look["treatment_only"] for look in record["looks"]] == [5, 6]
    assert record["looks"][0]["e_value"] == pytest.approx(63 / 6)
    assert record["looks"][1]["e_value"] == pytest.approx(127 / 7)
    assert record["rejected"] and record["stopped"] and record["stopped_at_look"] == 1
    assert record["n_used"] == 20 and record["look_every"] == 10
    # the same pairs with a 30-state tail: they ran past the stop
    with pytest.raises(ValueError, match="go past the look that stopped"):
        sequential.stopping_record(
            np.concatenate([a, np.zeros(10, bool)]),
            np.zeros(30, bool),
            stopping=stopping(10, 100),
        )


def test_without_a_rejection_the_run_goes_to_max_n():
    a = np.array([1, 0] * 15, dtype=bool)
    b = np.array([0, 1] * 15, dtype=bool)
    record = sequential.stopping_record(a[:20], b[:20], stopping=stopping(10, 30))
    assert not record["stopped"] and record["stopped_at_look"] is None
    record = sequential.stopping_record(a, b, stopping=stopping(10, 30))
    assert record["stopped"] and not record["rejected"] and record["n_used"] == 30
    with pytest.raises(ValueError, match="whole blocks of 10"):
        sequential.stopping_record(a[:15], b[:15], stopping=stopping(10, 30))


# -- the threshold calibrated to the maximum N ------------------------------------------------


def crossing_by_enumeration(max_n: int, threshold: float) -> float:
    """P(the e-value reaches `threshold` after some of the first max_n discordant pairs) under
    the null, by walking every one of the 2^max_n sequences of wins and losses (the e-value
    from the closed form written out above, not the module's)."""
    crossed = 0.0
    for path in range(2**max_n):
        wins = 0
        for d in range(1, max_n + 1):
            wins += (path >> (d - 1)) & 1
            if mixture_by_betaln(wins, d) >= threshold:
                crossed += 0.5**max_n
                break
    return crossed


@pytest.mark.parametrize("threshold", [4.0, 7.0, 10.6])
def test_the_crossing_probability_is_exact(threshold):
    assert sequential.null_crossing_probability(14, math.log(threshold)) == pytest.approx(
        crossing_by_enumeration(14, threshold), abs=1e-14
    )


@pytest.mark.parametrize(("max_n", "alpha"), [(200, 0.05), (200, 0.025), (60, 0.025)])
def test_the_threshold_is_the_smallest_whose_error_within_n_is_at_most_alpha(max_n, alpha):
    found = sequential.calibrated_threshold(max_n, alpha)
    threshold = found["threshold"]
    assert threshold < 1 / alpha  # below Ville's, which holds for unboundedly many pairs
    # every e-value the rule can meet within N pairs; the largest below the threshold, as a
    # threshold, is reached with probability above alpha: no smaller threshold would do
    values = np.array(
        [mixture_by_betaln(k, d) for d in range(1, max_n + 1) for k in range(d // 2, d + 1)]
    )
    below = values[values < threshold].max()
    # the walk over the wins after each of N discordant pairs, here from scipy's binomial
    bound = crossing_by_binomial_walk(max_n, threshold)
    assert bound == pytest.approx(found["error_bound"], abs=1e-12)
    assert bound <= alpha < crossing_by_binomial_walk(max_n, below)
    if (max_n, alpha) == (200, 0.05):
        assert threshold == pytest.approx(13.7, abs=0.05)


def crossing_by_binomial_walk(max_n: int, threshold: float) -> float:
    """The same probability from the first-passage decomposition: the chance of being at k
    wins after d pairs without having crossed, propagated by one Bernoulli(1/2) pair at a time
    with scipy's binomial pmf (an independent way to the same number)."""
    from scipy.stats import binom

    step = binom.pmf([0, 1], 1, 0.5)
    alive = np.array([1.0])
    crossed = 0.0
    for d in range(1, max_n + 1):
        alive = np.convolve(alive, step)
        e = np.array([mixture_by_betaln(k, d) for k in range(d + 1)])
        crossed += alive[e >= threshold].sum()
        alive[e >= threshold] = 0.0
    return crossed


def test_a_maximum_n_past_the_calibration_keeps_one_over_alpha():
    found = sequential.calibrated_threshold(sequential.CALIBRATED_MAX_N + 1, 0.025)
    assert found["threshold"] == 40.0 and "Ville" in found["method"]


def test_the_record_uses_the_calibrated_threshold():
    # 6 of 6 discordant pairs to the treatment: e = 18.1, at N = 200 and alpha 0.05 past the
    # calibrated 13.7 though short of 1/alpha = 20
    a = np.array([1] * 6 + [0] * 14, dtype=bool)
    record = sequential.stopping_record(a, np.zeros(20, bool), stopping=stopping(20, 200))
    assert record["threshold"] == sequential.calibrated_threshold(200, 0.05)["threshold"]
    assert record["looks"][0]["e_value"] == pytest.approx(127 / 7)
    assert record["rejected"] and record["n_used"] == 20


def test_operating_characteristics_match_every_path():
    # 8 states, a look after every 2: walk all 3^8 sequences of win / loss / tie
    p_win, p_loss, threshold, max_n, every = 0.3, 0.1, 3.0, 8, 2
    power = mean_n = 0.0
    for path in np.ndindex(*(3,) * max_n):
        prob = math.prod((p_win, p_loss, 1 - p_win - p_loss)[x] for x in path)
        wins = losses = 0
        used, rejected = max_n, False
        for i, x in enumerate(path, start=1):
            wins += x == 0
            losses += x == 1
            if i % every == 0 and mixture_by_betaln(wins, wins + losses) >= threshold:
                used, rejected = i, True
                break
        power += prob * rejected
        mean_n += prob * used
    got = sequential.operating_characteristics(
        max_n=max_n, look_every=every, p_win=p_win, p_loss=p_loss, threshold=threshold
    )
    assert got["power"] == pytest.approx(power, abs=1e-12)
    assert got["mean_n"] == pytest.approx(mean_n, abs=1e-12)


def with_stopping(edit=None) -> dict:
    config = copy.deepcopy(BASE)
    config["stopping"] = dict(RULE)
    if edit:
        edit(config)
    return config


def test_a_stopping_section_passes_the_config_check():
    check_config(with_stopping(), source=SOURCE, repo_root=REPO_ROOT)


@pytest.mark.parametrize(
    ("edit", "message"),
    [
        (lambda c: c["stopping"].update(alpha=0.7), "stopping.alpha: expected <= 0.5, got 0.7"),
        (
            lambda c: c["stopping"].update(rule="sprt"),
            "stopping.rule: expected one of ['mixture_sprt'], got 'sprt'",
        ),
        (
            lambda c: c["design"]["falsifier"].update(threshold=0.1),
            "design.falsifier.threshold: expected 0 with a stopping rule (its null is no paired "
            "difference), got 0.1",
        ),
        (
            lambda c: c["stopping"].pop("look_every"),
            "stopping.look_every: missing; this key is required",
        ),
        (
            lambda c: c["stopping"].update(look_every=200),
            "stopping.look_every: expected fewer than states.n (200) states between looks, or "
            "the rule cannot stop before N, got 200",
        ),
        (
            lambda c: (c["states"].update(n=8), c["stopping"].update(look_every=4)),
            "stopping.look_every: expected a look before N at which the rule can stop: at the "
            "last one (4 states) even every pair to slow gives an e-value of 6.2, under the "
            "threshold 10.5 (N = 8, alpha 0.025), got 4",
        ),
        (
            lambda c: c["stopping"].update(alpha=0.05),
            "stopping.alpha: expected at most 0.025, the one-sided error of the falsifier's "
            "verdict at analysis.confidence 0.95 (the stopping rule's test decides it), got 0.05",
        ),
    ],
)
def test_a_bad_stopping_section_is_one_line(edit, message):
    with pytest.raises(ConfigError) as err:
        check_config(with_stopping(edit), source=SOURCE, repo_root=REPO_ROOT)
    assert str(err.value).startswith(f"{SOURCE}: {message}")


def test_the_report_section_says_what_the_stop_licenses():
    from mjtrial.report.stopping import stopping_section

    paired = {"paired_difference": {"treatment": "slow", "baseline": "fast"}}
    assert stopping_section(paired) == []
    a = np.array([1] * 7 + [0] * 3, dtype=bool)
    rule = sequential.stopping_record(a, np.zeros(10, bool), stopping=stopping(10, 100))
    text = "\n".join(stopping_section({**paired, "stopping": rule}))
    assert "| 0 | 10 | 7/7 | 31.9 |" in text
    assert "Stopped at look 0, after 10 of 100 states" in text
    assert "not adjusted for the stop" in text and "no confidence sequence" in text
    b = np.array([0, 1] * 15, dtype=bool)
    rule = sequential.stopping_record(~b, b, stopping=stopping(10, 30))
    text = "\n".join(stopping_section({**paired, "stopping": rule}))
    assert f"never reached {rule['threshold']:.4g}: all 30 states ran" in text
    assert "the falsifier is refuted by this test" in text


# -- the falsifier's verdict under a stopping rule: one decision, one error budget -------------


def false_survive_rate(*, max_n: int, look_every: int, discordance: float, alpha: float) -> float:
    """The exact chance under the null that the verdict is "survives": the rule's test rejects
    at some look (the last at max_n). Each state is a treatment win or a baseline win with
    probability discordance / 2 each; the wins and losses between looks are trinomial
    (scipy's), propagated look by look with the stopped runs taken out."""
    from scipy.signal import fftconvolve
    from scipy.stats import multinomial

    threshold = math.log(sequential.calibrated_threshold(max_n, alpha)["threshold"])
    k = np.arange(max_n + 1)[:, None]
    d = k + np.arange(max_n + 1)[None, :]
    rejects = (d <= max_n) & (sequential.log_e_value(k, np.minimum(d, max_n)) >= threshold)
    alive = np.zeros((max_n + 1, max_n + 1))
    alive[0, 0] = 1.0
    survived = 0.0
    looks = [*range(look_every, max_n, look_every), max_n]
    for before, n in zip([0, *looks[:-1]], looks, strict=True):
        m = n - before
        i, j = np.meshgrid(np.arange(m + 1), np.arange(m + 1), indexing="ij")
        step = np.where(
            i + j <= m,
            multinomial.pmf(
                np.stack([i, j, np.maximum(m - i - j, 0)], axis=-1),
                m,
                [discordance / 2, discordance / 2, 1 - discordance],
            ),
            0.0,
        )
        alive = fftconvolve(alive, step)[: max_n + 1, : max_n + 1].clip(0.0)
        survived += alive[rejects].sum()
        alive[rejects] = 0.0
    return survived


@pytest.mark.parametrize("look_every", [1, 20, 199])
def test_the_verdict_under_a_stopping_rule_errs_at_most_alpha(look_every):
    """Computed exactly over every outcome, N = 200: a look after every state, every 20, or
    one before N and one at N; discordance rates from rare to every pair."""
    for discordance in (0.05, 0.2, 0.5, 1.0):
        rate = false_survive_rate(
            max_n=200, look_every=look_every, discordance=discordance, alpha=0.025
        )
        assert 0.0 < rate <= 0.025, (look_every, discordance, rate)


def summary_with_stopping(treatment, baseline, look_every: int, max_n: int) -> dict:
    from mjtrial.analysis import summarize

    n = treatment.size
    outcomes = {
        name: {
            "state_id": np.arange(n),
            "success": s,
            "nonfinite": np.zeros(n, bool),
            "warning": np.array([""] * n, object),
            "failure_category": np.array([None if ok else "never grasped" for ok in s], object),
        }
        for name, s in (("slow", treatment), ("fast", baseline))
    }
    record = sequential.stopping_record(
        treatment, baseline, stopping=stopping(look_every, max_n, alpha=0.025)
    )
    return summarize(
        states={"state_id": np.arange(n)},
        outcomes=outcomes,
        nominal={"slow": True, "fast": True},
        condition_parameters={"slow": {}, "fast": {}},
        falsifier={
            "treatment": "slow",
            "baseline": "fast",
            "statistic": "paired_difference",
            "threshold": 0.0,
        },
        analysis={"n_resamples": 500, "confidence": 0.95, "seed": 1, "bands": {}, "first_k": 5},
        stopping=record,
    )


def test_at_n_the_verdict_is_the_rules_test_not_a_second_one():
    # 60 states, 15 discordant pairs of which 12 to the treatment: the exact test and the
    # interval at N both exclude no difference, the rule's e-value (8.4) stays under its
    # threshold (18.1 for N = 60): one test decides, and it says why the interval differs
    treatment = np.array([1] * 12 + [0] * 3 + [1] * 45, dtype=bool)
    baseline = np.array([0] * 12 + [1] * 3 + [1] * 45, dtype=bool)
    order = np.random.default_rng(3).permutation(60)
    summary = summary_with_stopping(treatment[order], baseline[order], 20, 60)
    rule = summary["stopping"]
    assert not rule["rejected"] and rule["n_used"] == 60
    assert summary["paired_difference"]["low"] > 0 and summary["mcnemar"]["p_value"] < 0.05
    falsifier = summary["falsifier"]
    assert falsifier["verdict"] == "refuted"
    assert (
        falsifier["decision"] == "the stopping rule's one-sided test, over every look up to "
        "the maximum N"
    )
    assert "never reached its threshold" in falsifier["reason"]
    assert "but the verdict is the test's" in falsifier["reason"]


def test_an_early_stop_is_the_verdict():
    treatment = np.array([1] * 8 + [0] * 12, dtype=bool)
    summary = summary_with_stopping(treatment, np.zeros(20, bool), 20, 200)
    assert summary["stopping"]["rejected"] and summary["n_states"] == 20
    assert summary["falsifier"]["verdict"] == "survives"
    assert "reached its threshold" in summary["falsifier"]["reason"]
