"""The benchmark's summary: every number its report gives, from the evaluation outcomes.

`outcomes[task][method][seed]` is a boolean array, one entry per evaluation state of the task
in state order (the same states for every method and seed: paired). The summary keeps the two
overall rates apart, each labelled (`episode_mean`, `task_mean`), gives the rliable aggregates
over training seeds, the spread over seeds (never the best seed alone), paired differences per
task with Holm-adjusted McNemar tests, and every method's budget with any asymmetry flagged.

A method need not run on every task (`outcomes[task]` may lack it: a policy file trained for
one task). Its cells there are absent, never filled: its overall rates and IQM are over the
tasks it ran, which its entry then lists (`overall.<method>.tasks`, and `not_run`), and two
methods are compared on the tasks both ran.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np

from mjtrial.benchmark import stats as bstats
from mjtrial.stats import wilson_interval

# The performance profile's thresholds: success rates from 0 to 1.
PROFILE_TAUS = tuple(round(t, 2) for t in np.linspace(0.0, 1.0, 21))

Outcomes = Mapping[str, Mapping[str, Mapping[int, np.ndarray]]]


def _interval(estimate: float, low: float, high: float) -> dict[str, float]:
    return {"estimate": float(estimate), "low": float(low), "high": float(high)}


def _rate(success: np.ndarray, confidence: float) -> dict[str, Any]:
    k, n = int(np.sum(success)), int(np.size(success))
    low, high = wilson_interval(k, n, confidence)
    return {"successes": k, "n": n, "rate": k / n, "low": low, "high": high}


def summarize_benchmark(
    outcomes: Outcomes,
    *,
    budgets: Mapping[str, int],
    episodes_used: Mapping[str, Mapping[str, Mapping[int, int]]],
    headline: str,
    unequal_budgets: str | None,
    analysis: Mapping[str, Any],
    methods: Sequence[str] | None = None,
) -> dict[str, Any]:
    """The summary (JSON-able). `episodes_used[task][method][seed]`: what each training spent.
    `analysis`: `confidence`, `n_resamples`, `seed`. `methods`: every method, in order
    (default: the first task's)."""
    confidence, n_resamples, seed = (
        analysis["confidence"],
        analysis["n_resamples"],
        analysis["seed"],
    )
    tasks = list(outcomes)
    methods = list(next(iter(outcomes.values())) if methods is None else methods)
    ran = {m: [t for t in tasks if m in outcomes[t]] for m in methods}
    seeds = sorted(outcomes[ran[methods[0]][0]][methods[0]])
    label = bstats.seed_count_label(len(seeds))

    per_task: dict[str, Any] = {}
    for task in tasks:
        per_task[task] = {}
        for method in (m for m in methods if task in ran[m]):
            by_seed = outcomes[task][method]
            rates = [float(np.mean(by_seed[s])) for s in seeds]
            spread = bstats.seed_spread(rates)
            per_task[task][method] = {
                "per_seed": {str(s): _rate(by_seed[s], confidence) for s in seeds},
                "pooled_over_seeds": _rate(np.concatenate([by_seed[s] for s in seeds]), confidence),
                "spread_over_seeds": {
                    "min": spread.minimum,
                    "median": spread.median,
                    "max": spread.maximum,
                },
            }

    overall: dict[str, Any] = {}
    for i, method in enumerate(methods):
        own = ran[method]  # the tasks it ran: its overall rates are over these
        per_seed = {
            str(s): {
                "episode_mean": _interval(
                    *bstats.episode_mean([outcomes[t][method][s] for t in own], confidence)
                ),
                "task_mean": _interval(
                    *bstats.task_mean([outcomes[t][method][s] for t in own], confidence)
                ),
            }
            for s in seeds
        }
        scores = np.array([[np.mean(outcomes[t][method][s]) for t in own] for s in seeds])
        iqm = bstats.stratified_bootstrap_ci(
            scores, n_resamples=n_resamples, confidence=confidence, seed=seed + i
        )
        profile, low, high = bstats.performance_profile_ci(
            scores, PROFILE_TAUS, n_resamples=n_resamples, confidence=confidence, seed=seed + i
        )
        overall[method] = {
            **({"tasks": own} if own != tasks else {}),
            "episode_mean": {
                "per_seed": {s: v["episode_mean"] for s, v in per_seed.items()},
                "spread_over_seeds": _spread(
                    [v["episode_mean"]["estimate"] for v in per_seed.values()]
                ),
            },
            "task_mean": {
                "per_seed": {s: v["task_mean"] for s, v in per_seed.items()},
                "spread_over_seeds": _spread(
                    [v["task_mean"]["estimate"] for v in per_seed.values()]
                ),
            },
            "iqm": _interval(*iqm),
            "performance_profile": {
                "taus": list(PROFILE_TAUS),
                "fraction": profile.tolist(),
                "low": low.tolist(),
                "high": high.tolist(),
            },
        }

    comparisons = []
    for i, a in enumerate(methods):
        for b in methods[i + 1 :]:
            both = [t for t in tasks if t in ran[a] and t in ran[b]]
            if not both:
                continue
            pooled_a = {t: np.concatenate([outcomes[t][a][s] for s in seeds]) for t in both}
            pooled_b = {t: np.concatenate([outcomes[t][b][s] for s in seeds]) for t in both}
            for c in bstats.compare_methods(pooled_a, pooled_b, alpha=1 - confidence):
                comparisons.append(
                    {
                        "a": a,
                        "b": b,
                        "task": c.task,
                        "pairs": c.n_pairs,
                        "rate_a": c.rate_a,
                        "rate_b": c.rate_b,
                        "difference": c.difference,
                        "only_a": c.only_a,
                        "only_b": c.only_b,
                        "p_value": c.p_value,
                        "p_holm": c.p_holm,
                        "significant": c.significant,
                    }
                )

    not_run = {m: [t for t in tasks if t not in ran[m]] for m in methods if ran[m] != tasks}
    return {
        "tasks": tasks,
        "methods": methods,
        **({"not_run": not_run} if not_run else {}),
        "seeds": seeds,
        "result": label,
        "headline": headline,
        "overall_rates": {
            "episode_mean": "every episode of every task pooled: more states, more weight",
            "task_mean": "the mean of the per-task rates: every task weighs the same",
            **(
                {"tasks": "each method's over the tasks it ran (not_run: the others)"}
                if not_run
                else {}
            ),
        },
        "per_task": per_task,
        "overall": overall,
        "comparisons": comparisons,
        "comparisons_method": (
            "exact McNemar per task on pairs (training seed, evaluation state), Holm-adjusted "
            "across the tasks of each pair of methods"
        ),
        "budgets": {
            m: {
                "episodes": budgets[m],
                "used": {t: {str(s): episodes_used[t][m][s] for s in seeds} for t in ran[m]},
            }
            for m in methods
        },
        "unequal_budgets": unequal_budgets if len(set(budgets.values())) > 1 else None,
        "intervals": {
            "rate": "Wilson",
            "episode_mean": bstats.EPISODE_MEAN_METHOD,
            "task_mean": bstats.TASK_MEAN_METHOD,
            "iqm": bstats.STRATIFIED_BOOTSTRAP_METHOD,
            "confidence": confidence,
            "n_resamples": n_resamples,
        },
    }


def _spread(values: list[float]) -> dict[str, float]:
    s = bstats.seed_spread(values)
    return {"min": s.minimum, "median": s.median, "max": s.maximum}
