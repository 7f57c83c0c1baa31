"""The benchmark's summary (mjtrial.benchmark.summary) against independent computations: the
course's 80 % / 50 % example, per-seed rates, IQM over seeds (scipy's trimmed mean), Holm over
the tasks, the budgets and their asymmetry."""

from __future__ import annotations

import numpy as np
import pytest
from scipy import stats as sps

from mjtrial.benchmark.summary import summarize_benchmark

ANALYSIS = {"confidence": 0.95, "n_resamples": 500, "seed": 3}


def outcomes_of(table):
    return {
        t: {m: {s: np.asarray(v, dtype=bool) for s, v in seeds.items()} for m, seeds in ms.items()}
        for t, ms in table.items()
    }


def test_the_courses_example_gives_80_percent_over_episodes_and_50_over_tasks():
    """8 episodes of an easy task all succeeding, 2 of a hard task all failing."""
    table = {
        "easy": {"m": {s: [1] * 8 for s in range(3)}},
        "hard": {"m": {s: [0] * 2 for s in range(3)}},
    }
    summary = summarize_benchmark(
        outcomes_of(table),
        budgets={"m": 0},
        episodes_used={
            "easy": {"m": dict.fromkeys(range(3), 0)},
            "hard": {"m": dict.fromkeys(range(3), 0)},
        },
        headline="task_mean",
        unequal_budgets=None,
        analysis=ANALYSIS,
    )
    overall = summary["overall"]["m"]
    for s in ("0", "1", "2"):
        assert overall["episode_mean"]["per_seed"][s]["estimate"] == pytest.approx(0.8)
        assert overall["task_mean"]["per_seed"][s]["estimate"] == pytest.approx(0.5)
    low, high = sps.binomtest(8, 10).proportion_ci(0.95, method="wilson")
    assert overall["episode_mean"]["per_seed"]["0"]["low"] == pytest.approx(low)
    assert overall["episode_mean"]["per_seed"]["0"]["high"] == pytest.approx(high)
    assert summary["result"] == "development decision"  # 3 seeds
    assert set(summary["overall_rates"]) == {"episode_mean", "task_mean"}


def test_rates_iqm_spread_and_holm_against_independent_computations():
    rng = np.random.default_rng(0)
    n, seeds = 40, range(5)
    truth = {"a": {"x": 0.9, "y": 0.4}, "b": {"x": 0.6, "y": 0.45}}
    table = {
        t: {m: {s: rng.random(n) < truth[m][t] for s in seeds} for m in truth} for t in ("x", "y")
    }
    used = {t: {m: {s: 0 if m == "b" else 120 for s in seeds} for m in truth} for t in table}
    summary = summarize_benchmark(
        outcomes_of(table),
        budgets={"a": 120, "b": 0},
        episodes_used=used,
        headline="episode_mean",
        unequal_budgets="b tunes nothing",
        analysis=ANALYSIS,
    )
    assert summary["result"] == "reported result"
    for t in table:
        for m in truth:
            rates = [np.mean(table[t][m][s]) for s in seeds]
            rec = summary["per_task"][t][m]
            assert [rec["per_seed"][str(s)]["rate"] for s in seeds] == pytest.approx(rates)
            assert rec["spread_over_seeds"] == pytest.approx(
                {"min": min(rates), "median": float(np.median(rates)), "max": max(rates)}
            )
            pooled = np.concatenate([table[t][m][s] for s in seeds])
            assert rec["pooled_over_seeds"]["successes"] == int(pooled.sum())
    for m in truth:
        scores = [[np.mean(table[t][m][s]) for t in table] for s in seeds]
        iqm = summary["overall"][m]["iqm"]
        assert iqm["estimate"] == pytest.approx(sps.trim_mean(np.ravel(scores), 0.25))
        assert iqm["low"] <= iqm["estimate"] <= iqm["high"]
    # McNemar per task on (seed, state) pairs, then Holm by hand over the two tasks.
    p = {}
    for t in table:
        a = np.concatenate([table[t]["a"][s] for s in seeds])
        b = np.concatenate([table[t]["b"][s] for s in seeds])
        only_a, only_b = int(np.sum(a & ~b)), int(np.sum(~a & b))
        p[t] = sps.binomtest(only_a, only_a + only_b, 0.5).pvalue if only_a + only_b else 1.0
    small, large = sorted(p, key=p.get)
    holm = {small: min(1.0, 2 * p[small])}
    holm[large] = min(1.0, max(holm[small], p[large]))
    for c in summary["comparisons"]:
        assert (c["a"], c["b"]) == ("a", "b")
        assert c["p_value"] == pytest.approx(p[c["task"]])
        assert c["p_holm"] == pytest.approx(holm[c["task"]])
    assert summary["unequal_budgets"] == "b tunes nothing"
    assert summary["budgets"]["a"]["episodes"] == 120 and summary["budgets"]["b"]["episodes"] == 0


def test_fewer_than_three_seeds_is_refused():
    table = {"x": {"m": {0: [1, 0], 1: [1, 1]}}}
    with pytest.raises(ValueError, match="n_seeds must be >= 3"):
        summarize_benchmark(
            outcomes_of(table),
            budgets={"m": 0},
            episodes_used={"x": {"m": {0: 0, 1: 0}}},
            headline="task_mean",
            unequal_budgets=None,
            analysis=ANALYSIS,
        )


def test_the_performance_profile_figure_draws_each_methods_profile_and_band():
    """The course's example plus a second method: the figure's steps are the fractions of
    (seed, task) rates above each threshold, counted here, and each band is drawn."""
    from matplotlib.collections import PolyCollection

    from mjtrial.report.figures import figure_performance_profile

    table = {
        "easy": {
            "m": {s: [1] * 8 for s in range(3)},
            "n": {s: [1] * 4 + [0] * 4 for s in range(3)},
        },
        "hard": {"m": {s: [0] * 2 for s in range(3)}, "n": {s: [1, 0] for s in range(3)}},
    }
    summary = summarize_benchmark(
        outcomes_of(table),
        budgets={"m": 0, "n": 0},
        episodes_used={t: {m: dict.fromkeys(range(3), 0) for m in ("m", "n")} for t in table},
        headline="task_mean",
        unequal_budgets=None,
        analysis=ANALYSIS,
    )
    fig = figure_performance_profile(summary=summary)
    [ax] = fig.axes
    taus = np.linspace(0, 1, 21)
    # m: rates 1.0 (easy) and 0.0 (hard) in every seed; n: 0.5 and 0.5
    expected = {"m": [0.5] * 20 + [0.0], "n": [1.0 if t < 0.5 else 0.0 for t in taus]}
    for line, method in zip(ax.get_lines(), ("m", "n"), strict=True):
        assert line.get_label() == method
        np.testing.assert_allclose(line.get_xdata(), taus)
        np.testing.assert_allclose(line.get_ydata(), expected[method], atol=1e-12)
    assert len([c for c in ax.collections if isinstance(c, PolyCollection)]) == 2


def test_a_method_not_run_on_a_task_has_no_cell_and_its_rates_are_over_its_own_tasks():
    """Method `c` (a policy trained for task x) is not run on y: its overall rates and IQM are
    over x alone (scipy's trimmed mean of its per-seed rates there), labelled; it is compared
    with the others on x only; the others' numbers are those of a summary without it."""
    rng = np.random.default_rng(1)
    n, seeds = 30, range(5)
    table = {
        "x": {
            m: {s: rng.random(n) < p for s in seeds}
            for m, p in (("a", 0.8), ("b", 0.5), ("c", 0.6))
        },
        "y": {m: {s: rng.random(n) < p for s in seeds} for m, p in (("a", 0.3), ("b", 0.4))},
    }

    def summary_of(table, methods):
        used = {t: {m: dict.fromkeys(seeds, 0) for m in ms} for t, ms in table.items()}
        return summarize_benchmark(
            outcomes_of(table),
            methods=methods,
            budgets=dict.fromkeys(methods, 0),
            episodes_used=used,
            headline="task_mean",
            unequal_budgets=None,
            analysis=ANALYSIS,
        )

    summary = summary_of(table, ["a", "b", "c"])
    rates = [float(np.mean(table["x"]["c"][s])) for s in seeds]
    c = summary["overall"]["c"]
    assert c["tasks"] == ["x"] and summary["not_run"] == {"c": ["y"]}
    assert c["iqm"]["estimate"] == pytest.approx(sps.trim_mean(rates, 0.25))
    assert [c["task_mean"]["per_seed"][str(s)]["estimate"] for s in seeds] == pytest.approx(rates)
    assert set(summary["per_task"]["y"]) == {"a", "b"}
    assert {(k["a"], k["b"], k["task"]) for k in summary["comparisons"]} == {
        ("a", "b", "x"),
        ("a", "b", "y"),
        ("a", "c", "x"),
        ("b", "c", "x"),
    }
    assert summary["budgets"]["c"]["used"] == {"x": dict.fromkeys(map(str, seeds), 0)}
    without = summary_of(
        {t: {m: v for m, v in ms.items() if m != "c"} for t, ms in table.items()}, ["a", "b"]
    )
    for m in ("a", "b"):
        assert "tasks" not in summary["overall"][m]
        assert summary["overall"][m] == without["overall"][m]
    assert "not_run" not in without
