"""Dose-response: the trend against a hand-written clustered logistic fit, Holm by hand."""

from __future__ import annotations

from statistics import NormalDist

import numpy as np
import pytest

from mjtrial.studies.dose_response import summarize_dose_response, trend

ANALYSIS = {"confidence": 0.95, "n_resamples": 300, "seed": 11}
N = 20


def table(success):
    success = np.asarray(success, dtype=bool)
    return {"state_id": np.arange(success.size), "success": success}


def states():
    return {"state_id": np.arange(N), "mass": np.linspace(0.05, 0.6, N)}


def logistic_cluster_reference(x, y, groups, confidence):
    """Newton's method for the logistic MLE, then the cluster sandwich with the small-sample
    factor G/(G-1) (N-1)/(N-K), and a normal interval."""
    X = np.column_stack([np.ones_like(x), x])
    beta = np.zeros(2)
    for _ in range(100):
        mu = 1 / (1 + np.exp(-X @ beta))
        hessian = X.T @ (X * (mu * (1 - mu))[:, None])
        beta = beta + np.linalg.solve(hessian, X.T @ (y - mu))
    mu = 1 / (1 + np.exp(-X @ beta))
    bread = np.linalg.inv(X.T @ (X * (mu * (1 - mu))[:, None]))
    scores = X * (y - mu)[:, None]
    meat = np.zeros((2, 2))
    clusters = np.unique(groups)
    for g in clusters:
        s = scores[groups == g].sum(axis=0)
        meat += np.outer(s, s)
    n, k, G = len(y), 2, len(clusters)
    cov = bread @ meat @ bread * G / (G - 1) * (n - 1) / (n - k)
    se = float(np.sqrt(cov[1, 1]))
    z = NormalDist().inv_cdf(0.5 + confidence / 2)
    return beta[1], se, beta[1] - z * se, beta[1] + z * se


def test_trend_matches_a_hand_written_clustered_logistic_fit():
    rng = np.random.default_rng(5)
    values = np.array([0.15, 0.3, 0.6, 1.5])
    state_effect = rng.normal(0, 1, N)  # outcomes correlated within a state
    x = np.log(np.repeat(values, N))
    groups = np.tile(np.arange(N), len(values))
    p = 1 / (1 + np.exp(-(1.0 + 0.8 * x + state_effect[groups])))
    y = rng.random(x.size) < p
    got = trend(np.exp(x), y, groups, confidence=0.9)
    slope, se, low, high = logistic_cluster_reference(x, y.astype(float), groups, 0.9)
    assert got["slope_log_odds_per_log_value"] == pytest.approx(slope, rel=1e-8)
    assert got["standard_error"] == pytest.approx(se, rel=1e-8)
    assert (got["low"], got["high"]) == pytest.approx((low, high), rel=1e-8)
    assert got["odds_ratio_per_doubling"] == pytest.approx(2**slope, rel=1e-8)


def test_trend_on_the_linear_scale_matches_the_fit_on_the_value_itself():
    """A sweep from 0 (a latency) is fitted on the value: same reference, x not logged."""
    rng = np.random.default_rng(6)
    values = np.array([0.0, 0.01, 0.02, 0.04])
    x = np.repeat(values, N)
    groups = np.tile(np.arange(N), len(values))
    y = rng.random(x.size) < 1 / (1 + np.exp(-(1.5 - 40.0 * x + rng.normal(0, 1, N)[groups])))
    got = trend(x, y, groups, confidence=0.95, scale="linear")
    slope, se, low, high = logistic_cluster_reference(x, y.astype(float), groups, 0.95)
    assert got["slope_log_odds_per_unit_value"] == pytest.approx(slope, rel=1e-8)
    assert (got["low"], got["high"]) == pytest.approx((low, high), rel=1e-8)
    assert got["odds_ratio_over_range"] == pytest.approx(np.exp(slope * 0.04), rel=1e-8)
    assert "log(value)" not in got["method"] and "on the value" in got["method"]


def test_a_sweep_through_zero_is_summarized_on_the_linear_scale():
    out = _summarize(_latency_sweep({0.0: 0, 0.02: 4, 0.04: 9}), margin=0.05, reference=0.0)
    assert out["scale"] == "linear" and out["unit"] == "s" and out["band_unit"] == "kg"
    assert out["trend"]["slope_log_odds_per_unit_value"] < 0
    assert out["values_within_margin"] == [0.0]
    assert out["toward"] == "larger" and out["furthest_within_margin"] == 0.0


def test_trend_slope_on_a_saturated_two_value_design():
    # Two values: the MLE slope is the difference of the empirical logits over that of log x.
    v = np.repeat([0.2, 1.0], 10)
    y = np.array([1] * 3 + [0] * 7 + [1] * 8 + [0] * 2, dtype=bool)
    expected = (np.log(8 / 2) - np.log(3 / 7)) / (np.log(1.0) - np.log(0.2))
    got = trend(v, y, np.tile(np.arange(10), 2), confidence=0.95)
    assert got["slope_log_odds_per_log_value"] == pytest.approx(expected, rel=1e-8)


def sweep():
    ok = np.ones(N, bool)

    def failing(k):  # the first k states fail, the rest succeed
        return table(np.r_[np.zeros(k, bool), np.ones(N - k, bool)])

    return {0.15: failing(8), 0.3: failing(5), 0.6: failing(3), 1.0: table(ok), 1.5: table(ok)}


def summarize_sweep():
    """The hand-built sweep summarized with two mass bands and a 0.05 margin."""
    return summarize_dose_response(
        sweep(),
        parameter="lift_time",
        states=states(),
        band_parameter="mass",
        band_edges=[0.05, 0.3, 0.6],
        analysis=ANALYSIS,
        margin=0.05,
    )


def test_each_value_against_the_slowest_with_holm_by_hand():
    out = summarize_sweep()
    assert out["reference"] == 1.5
    rows = {c["lift_time"]: c for c in out["comparisons"]}
    assert list(rows) == [0.15, 0.3, 0.6, 1.0]
    # Every discordant pair favours the reference: exact two-sided p = 2 * 0.5**k.
    raw = {0.15: 2 * 0.5**8, 0.3: 2 * 0.5**5, 0.6: 2 * 0.5**3, 1.0: 1.0}
    for v, p in raw.items():
        assert rows[v]["p_value"] == pytest.approx(p, rel=1e-12)
    # Holm, m = 4: sorted p times (4, 3, 2, 1), then a running maximum, capped at 1.
    holm = {0.15: 4 * raw[0.15], 0.3: 3 * raw[0.3], 0.6: max(3 * raw[0.3], 2 * raw[0.6]), 1.0: 1.0}
    for v, p in holm.items():
        assert rows[v]["p_holm"] == pytest.approx(p, rel=1e-12)
    assert [rows[v]["significant"] for v in rows] == [True, False, False, False]
    assert rows[0.15]["estimate"] == pytest.approx(-8 / N)
    # 1.0 equals the reference on every state: interval [0, 0], within any margin; 0.6 has
    # estimate -0.15, so its lower bound is below -0.05.
    assert (rows[1.0]["low"], rows[1.0]["high"]) == (0.0, 0.0)
    assert out["furthest_within_margin"] == 1.0 and out["toward"] == "smaller"


def test_rates_pooled_and_per_mass_band():
    out = summarize_sweep()
    first = out["per_value"][0]
    assert (first["lift_time"], first["successes"], first["n"]) == (0.15, 12, N)
    masses = states()["mass"]
    light = int((masses < 0.3).sum())  # states 0..light-1 are the lighter ones
    band = first["bands"]
    assert [b["n"] for b in band] == [light, N - light]
    assert band[0]["successes"] == light - 8 and band[1]["successes"] == N - light
    assert out["trend"]["slope_log_odds_per_log_value"] > 0


def test_a_wide_margin_admits_the_shortest_value_and_bad_sweeps_stop():
    out = summarize_dose_response(
        sweep(),
        parameter="lift_time",
        states=states(),
        band_parameter="mass",
        band_edges=[0.05, 0.6],
        analysis=ANALYSIS,
        margin=0.99,
    )
    assert out["furthest_within_margin"] == 0.15
    two = {k: v for k, v in sweep().items() if k in (0.15, 1.5)}
    with pytest.raises(ValueError, match="expected at least 3 values, got 2"):
        summarize_dose_response(
            two,
            parameter="lift_time",
            states=states(),
            band_parameter="mass",
            band_edges=[0.05, 0.6],
            analysis=ANALYSIS,
            margin=0.05,
        )


def test_trend_is_not_estimable_when_outcomes_are_separated():
    """Small samples can separate: every failure at the shortest value, every success after."""
    values = np.repeat([0.15, 0.3, 1.5], 4)
    success = values > 0.2
    groups = np.tile(np.arange(4), 3)
    result = trend(values, success, groups, confidence=0.95)
    assert result["not_estimable"]
    assert result["slope_log_odds_per_log_value"] is None and result["low"] is None
    result = trend(values, np.ones(12, dtype=bool), groups, confidence=0.95)
    assert result["not_estimable"]


def _latency_sweep(failures_by_value):
    """Latency tables in which the first k states fail at each value, the rest succeed."""
    return {
        v: table(np.r_[np.zeros(k, bool), np.ones(N - k, bool)])
        for v, k in failures_by_value.items()
    }


def _summarize(tables, **kwargs):
    return summarize_dose_response(
        tables,
        parameter="latency",
        states=states(),
        band_parameter="mass",
        band_edges=[0.05, 0.6],
        analysis=ANALYSIS,
        units={"latency": "s", "mass": "kg"},
        **kwargs,
    )


def test_the_furthest_value_goes_the_way_values_cost_and_stops_at_the_first_gap():
    # 0 ms the reference; 10 and 20 ms equal it on every state (interval [0, 0]); 30 ms loses
    # 12 of the 40 states (interval far below -0.05); 40 ms equals the reference again.
    tables = _latency_sweep({0.0: 0, 0.01: 0, 0.02: 0, 0.03: 12, 0.04: 0})
    out = _summarize(tables, margin=0.05, reference=0.0)
    assert out["toward"] == "larger"
    assert out["values_within_margin"] == [0.0, 0.01, 0.02, 0.04]
    assert out["furthest_within_margin"] == 0.02  # "up to 20 ms": 30 ms breaks the run
    assert (
        "largest latency such that it and every swept value between"
        in (out["within_margin_criterion"])
    )


def test_an_inside_reference_needs_a_direction():
    tables = _latency_sweep({0.0: 12, 0.01: 0, 0.02: 0, 0.03: 0})
    with pytest.raises(ValueError, match="toward: expected smaller or larger"):
        _summarize(tables, margin=0.05, reference=0.01)
    out = _summarize(tables, margin=0.05, reference=0.01, toward="larger")
    assert out["furthest_within_margin"] == 0.03
    assert (
        _summarize(tables, margin=0.05, reference=0.01, toward="smaller")["furthest_within_margin"]
        == 0.01
    )
