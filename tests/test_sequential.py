"""The stopping rule's test (mjtrial.sequential): the e-value against the mixture integral
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

from mjtrial import sequential
from mjtrial.config import ConfigError, check_config

SOURCE = "config/config.yaml"
BASE = yaml.safe_load((REPO_ROOT / SOURCE).read_text())
RULE = {"rule": "mixture_sprt", "alpha": 0.05}


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
    """Whether each simulated paired experiment's e-value reached 1/alpha at a look: each
    pair discordant with probability `discordance`, won by the treatment with `win`."""
    discordant = rng.random((n_experiments, max_n)) < discordance
    wins = discordant & (rng.random((n_experiments, max_n)) < win)
    looks = np.arange(block, max_n + 1, block) - 1
    d = np.cumsum(discordant, axis=1)[:, looks]
    k = np.cumsum(wins, axis=1)[:, looks]
    return (sequential.log_e_value(k, d) >= math.log(1 / alpha)).any(axis=1)


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


def stopping(block: int, max_n: int) -> dict:
    return {**RULE, "block": block, "max_n": max_n}


def test_the_record_stops_at_the_first_look_that_reaches_one_over_alpha():
    # 7 treatment-only pairs make e = (2^8 - 1)/8 = 31.9 >= 20; 6 make 18.1
    a = np.array([1] * 6 + [0] * 4 + [1] + [0] * 9, dtype=bool)
    b = np.zeros(20, dtype=bool)
    record = sequential.stopping_record(a, b, stopping=stopping(10, 100))
    assert [look["n"] for look in record["looks"]] == [10, 20]
    assert [look["treatment_only"] for look in record["looks"]] == [6, 7]
    assert record["looks"][0]["e_value"] == pytest.approx(127 / 7)
    assert record["looks"][1]["e_value"] == pytest.approx(255 / 8)
    assert record["rejected"] and record["stopped"] and record["stopped_at_look"] == 1
    assert record["n_used"] == 20
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
    ],
)
def test_a_bad_stopping_section_is_one_line(edit, message):
    with pytest.raises(ConfigError) as err:
        check_config(with_stopping(edit), source=SOURCE, repo_root=REPO_ROOT)
    assert str(err.value) == f"{SOURCE}: {message}"


def test_the_report_section_says_what_the_stop_licenses():
    from mjtrial.report.stopping import stopping_section

    paired = {"paired_difference": {"treatment": "slow", "baseline": "fast"}}
    assert stopping_section(paired) == []
    a = np.array([1] * 7 + [0] * 3, dtype=bool)
    rule = sequential.stopping_record(a, np.zeros(10, bool), stopping=stopping(10, 100))
    text = "\n".join(stopping_section({**paired, "stopping": rule}))
    assert "| 0 | 10 | 7/7 | 31.9 |" in text
    assert "Stopped at look 0, after 10 of 100 states" in text
    assert "not adjusted for it" in text
    b = np.array([0, 1] * 15, dtype=bool)
    rule = sequential.stopping_record(~b, b, stopping=stopping(10, 30))
    text = "\n".join(stopping_section({**paired, "stopping": rule}))
    assert "never reached 20: all 30 states ran" in text
