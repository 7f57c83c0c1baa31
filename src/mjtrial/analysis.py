"""From per-episode outcomes to the numbers a paper reports, and the falsifier's verdict.

Pure functions over arrays: the analysis rule reads the tables, calls `summarize`, and writes
the result; the printed table is rendered from the same summary, so the two cannot disagree.
"""

from __future__ import annotations

from collections import Counter
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np

from mjtrial import stats
from mjtrial.design.conditions import MODEL_EDITS, POLICY
from mjtrial.stats.comparisons import Comparison, exploratory, planned_comparisons
from mjtrial.task import UNHEALTHY

VERDICT_SURVIVES = "survives"
VERDICT_REFUTED = "refuted"
# Too many unhealthy episodes (a MuJoCo warning, a non-finite or halted state): the result is
# no evidence either way, whatever the interval says.
VERDICT_INVALID = "invalid"


def rate_record(success: np.ndarray, *, confidence: float) -> dict[str, Any]:
    """Successes, n, rate and Wilson interval of a boolean array of shape (n,)."""
    success = np.asarray(success, dtype=bool)
    n = int(success.size)
    k = int(success.sum())
    low, high = stats.wilson_interval(k, n, confidence) if n else (float("nan"),) * 2
    return {
        "n": n,
        "successes": k,
        "rate": k / n if n else None,
        "wilson_low": low if n else None,
        "wilson_high": high if n else None,
    }


# What a condition's summary record holds besides the protocol parameters it sets.
RESULT_KEYS = ("n", "successes", "rate", "wilson_low", "wilson_high", "unhealthy")


def condition_settings(record: Mapping[str, Any]) -> dict[str, Any]:
    """The protocol parameters a condition's summary record carries, in config order (its
    edits of the model, if any, are under `model`: `mjtrial.design.conditions.MODEL_EDITS`;
    its policy file under `policy`: `POLICY`)."""
    return {k: v for k, v in record.items() if k not in (*RESULT_KEYS, MODEL_EDITS, POLICY)}


def band_labels(edges: Sequence[float]) -> list[str]:
    """Labels of the bands [e0, e1), ..., [e(k-1), ek] (the last band is closed)."""
    labels = [f"[{a:g}, {b:g})" for a, b in zip(edges[:-1], edges[1:], strict=True)]
    labels[-1] = labels[-1][:-1] + "]"
    return labels


def band_index(values: np.ndarray, edges: Sequence[float]) -> np.ndarray:
    """Band of each value, 0..k-1; the last band includes its upper edge."""
    idx = np.searchsorted(np.asarray(edges), values, side="right") - 1
    return np.clip(idx, 0, len(edges) - 2)


def band_values(states: Mapping[str, np.ndarray], parameter: str) -> np.ndarray:
    """Values a band table sorts by: a state column, or its magnitude for `abs_<column>`."""
    if parameter.startswith("abs_"):
        return np.abs(np.asarray(states[parameter.removeprefix("abs_")], dtype=float))
    return np.asarray(states[parameter], dtype=float)


def band_table(
    values: np.ndarray,
    edges: Sequence[float],
    success: Mapping[str, np.ndarray],
    *,
    confidence: float,
) -> list[dict[str, Any]]:
    """Success per band of `values` (shape (n,)) for each condition's success (shape (n,))."""
    band = band_index(values, edges)
    return [
        {
            "band": label,
            "low": edges[i],
            "high": edges[i + 1],
            "n": int((band == i).sum()),
            "conditions": {
                name: rate_record(s[band == i], confidence=confidence)
                for name, s in success.items()
            },
        }
        for i, label in enumerate(band_labels(edges))
    ]


def failure_counts(categories: np.ndarray, order: Sequence[str]) -> dict[str, int]:
    """Failed episodes per category, in the task's order (zeros included), then any other
    category the episodes name.

    Args:
      categories: each episode's category name, or None for a success; shape (n,).
      order: the task's categories (`Task.category_names()`).
    """
    counts = Counter(c for c in categories if c is not None)
    return {c: counts[c] for c in [*order, *sorted(set(counts) - set(order))]}


def unhealthy(table: Mapping[str, np.ndarray]) -> np.ndarray:
    """Episodes of a rollout table that are unhealthy: a MuJoCo warning, a non-finite state, or
    classified "simulation unhealthy" (halted), shape `(n,)` booleans."""
    return (
        np.asarray(table["nonfinite"], dtype=bool)
        | (np.asarray(table["warning"], dtype=object) != "")
        | (np.asarray(table["failure_category"], dtype=object) == UNHEALTHY)
    )


def bound_of(table: Mapping[str, int]) -> str | None:
    """ "ceiling" when both conditions succeed in every state, "floor" when both fail in every
    state (no discordant pair, both rates 1 or both 0), else None; `table` is a comparison's
    paired table (both, only_<treatment>, only_<baseline>, neither)."""
    n = sum(table.values())
    if n and table["both"] == n:
        return "ceiling"
    if n and table["neither"] == n:
        return "floor"
    return None


# Why the bootstrap is not the comparison's interval (kept beside it, `replaces`).
BOOTSTRAP_UNDER_COVERS = (
    "the percentile bootstrap over pairs under-covers with few pairs or rates near 0 or 1 "
    "(exactly degenerate where every pair's difference is the same)"
)


def compare(
    a: np.ndarray, b: np.ndarray, *, comparison: Comparison, analysis: Mapping[str, Any]
) -> dict[str, Any]:
    """One planned comparison of success `a` (treatment) with `b` (baseline), shape (n,) each:
    the paired table, the exact McNemar test and the paired difference with its interval.

    The interval is Newcombe's hybrid score interval (method 10): its exact coverage stays near
    its nominal level at every n and rate (docs/guide/statistics.md gives the figures), where
    the percentile bootstrap over pairs falls to 0.85 with tens of pairs near 0 or 1. The
    bootstrap's interval (every comparison drawing the same resamples of states, the seed
    `analysis.seed`) is kept beside it (`replaces`) for comparison with earlier reports.
    """
    treatment, baseline = comparison.pair
    confidence = float(analysis["confidence"])
    estimate, low, high = stats.paired_difference_ci(
        a.astype(float),
        b.astype(float),
        n_resamples=int(analysis["n_resamples"]),
        confidence=confidence,
        seed=int(analysis["seed"]),
    )
    bootstrap = {
        "low": low,
        "high": high,
        "method": f"{stats.BOOTSTRAP_METHOD} over pairs",
        "n_resamples": int(analysis["n_resamples"]),
        "seed": int(analysis["seed"]),
        "why": "degenerate: every pair's difference the same"
        if low == high
        else BOOTSTRAP_UNDER_COVERS,
    }
    test = stats.mcnemar(a, b)
    table = {
        "both": int((a & b).sum()),
        f"only_{treatment}": test.only_a,
        f"only_{baseline}": test.only_b,
        "neither": int((~a & ~b).sum()),
    }
    _, new_low, new_high = stats.newcombe_paired_interval(*table.values(), confidence=confidence)
    paired = {
        "treatment": treatment,
        "baseline": baseline,
        "estimate": estimate,
        "low": new_low,
        "high": new_high,
        "method": stats.NEWCOMBE_METHOD,
        "confidence": confidence,
        "replaces": bootstrap,
    }
    return {
        "treatment": treatment,
        "baseline": baseline,
        "primary": comparison.primary,
        "exploratory": False,
        "table": table,
        "bound": bound_of(table),
        "mcnemar": {"p_value": test.p_value, "method": test.method},
        "paired_difference": paired,
    }


def correct_family(records: Sequence[dict[str, Any]], exploratory: Sequence[bool]) -> None:
    """Holm-adjust the comparisons' McNemar p-values in place (`mcnemar.p_holm`): the planned
    ones as one family; an exploratory one (not in the registration) over every comparison
    tested, so adding tests after the data never moves a registered comparison's p."""
    raw = [r["mcnemar"]["p_value"] for r in records]
    planned = [i for i, extra in enumerate(exploratory) if not extra]
    everything = stats.holm(raw)
    family = stats.holm([raw[i] for i in planned]) if planned else []
    for i, record in enumerate(records):
        record["exploratory"] = bool(exploratory[i])
        record["mcnemar"]["p_holm"] = everything[i]
    for i, adjusted in zip(planned, family, strict=True):
        records[i]["mcnemar"]["p_holm"] = adjusted


# How the verdict is decided, in words (the summary's `falsifier.decision`).
DECISION_INTERVAL = "the interval's lower bound against the threshold"
DECISION_EXACT = (
    "the exact McNemar test, one-sided in the falsifier's direction at (1 - confidence) / 2"
)
DECISION_SEQUENTIAL = "the stopping rule's one-sided test, over every look up to the maximum N"


def judge_falsifier(
    falsifier: Mapping[str, Any],
    paired: Mapping[str, float],
    *,
    test: Mapping[str, Any] | None = None,
    stopping: Mapping[str, Any] | None = None,
    n_unhealthy: int = 0,
    n_episodes: int = 1,
) -> dict[str, Any]:
    """Verdict of the preregistered falsifier: one decision with one error budget.

    - With a stopping rule (`stopping`, `mjtrial.stats.sequential.stopping_record`): survives when
      its test rejected no difference at some look, the last at the maximum N included; its
      one-sided error is at most `stopping.alpha` whatever the looks.
    - Else, at the threshold 0 with the exact test given (`test`: `p_value`, `treatment_only`,
      `baseline_only`, `alpha` = 1 - confidence): survives when the exact McNemar test
      rejects in the falsifier's direction (two-sided p at most alpha and more pairs to the
      treatment: one-sided at alpha / 2, the level a two-sided interval implies).
    - Else: refuted when the interval's lower bound is at or below the threshold.

    Where the interval and the decision disagree about the threshold, the reason says so and
    why. Invalid, whatever the decision, when more than the design's `max_unhealthy_share`
    (default 0) of the compared episodes (`n_episodes`, both conditions) are unhealthy: an
    unstable simulation is no evidence either way.
    """
    threshold = float(falsifier["threshold"])
    interval_above = paired["low"] > threshold
    statistic = (
        f"{falsifier['statistic']} ({falsifier['treatment']} - {falsifier['baseline']}) = "
        f"{paired['estimate']:+.3f}, interval [{paired['low']:+.3f}, {paired['high']:+.3f}]"
    )
    if stopping is not None:
        survives = bool(stopping["rejected"])
        last = stopping["looks"][-1] if stopping["looks"] else None
        where = (
            f"at look {last['look']} ({last['n']} states, {last['treatment_only']} of "
            f"{last['discordant']} discordant pairs to {falsifier['treatment']}, e-value "
            f"{last['e_value']:.3g})"
            if last
            else "(no look)"
        )
        decision = (
            f"the stopping rule's test (one-sided, alpha {stopping['alpha']:g}) "
            + ("reached" if survives else "never reached")
            + f" its threshold {stopping['threshold']:.3g} {where}"
        )
        method = DECISION_SEQUENTIAL
    elif threshold == 0 and test is not None:
        alpha = float(test["alpha"])
        survives = test["treatment_only"] > test["baseline_only"] and test["p_value"] <= alpha
        decision = (
            f"exact McNemar p = {test['p_value']:.3g} ({test['treatment_only']} pairs only "
            f"{falsifier['treatment']}, {test['baseline_only']} only {falsifier['baseline']}): "
            + ("rejects" if survives else "does not reject")
            + f" no difference in the falsifier's direction at one-sided {alpha / 2:g}"
        )
        method = DECISION_EXACT
    else:
        survives = interval_above
        decision = (
            f"lower bound {'above' if survives else 'at or below'} the threshold {threshold:g}"
        )
        method = DECISION_INTERVAL
    reason = f"{statistic}: {decision}"
    if method != DECISION_INTERVAL and interval_above != survives:
        reason += (
            f"; the interval's lower bound is {'above' if interval_above else 'at or below'} "
            f"{threshold:g}, but the verdict is the test's: the interval is an estimate "
            + (
                "on the states that ran, not adjusted for the looks"
                if stopping is not None
                else "of approximate coverage, the test exact"
            )
        )
    verdict = VERDICT_SURVIVES if survives else VERDICT_REFUTED
    allowed = float(falsifier.get("max_unhealthy_share", 0.0))
    if n_unhealthy > allowed * n_episodes:
        verdict = VERDICT_INVALID
        reason = (
            f"{n_unhealthy} of {n_episodes} episodes unhealthy (MuJoCo warning, non-finite state "
            f"or halted), more than the design allows ({allowed:g}): not evidence either way; "
            f"{reason}"
        )
    return {**dict(falsifier), "verdict": verdict, "decision": method, "reason": reason}


def exact_test(record: Mapping[str, Any], confidence: float) -> dict[str, Any]:
    """A comparison record's exact McNemar test as `judge_falsifier` reads it."""
    table = record["table"]
    return {
        "p_value": record["mcnemar"]["p_value"],
        "treatment_only": table[f"only_{record['treatment']}"],
        "baseline_only": table[f"only_{record['baseline']}"],
        "alpha": 1.0 - confidence,
    }


def summarize(
    *,
    states: Mapping[str, np.ndarray],
    outcomes: Mapping[str, Mapping[str, np.ndarray]],
    nominal: Mapping[str, bool],
    condition_parameters: Mapping[str, Mapping[str, float]],
    falsifier: Mapping[str, Any],
    analysis: Mapping[str, Any],
    sample_size: Mapping[str, Any] | None = None,
    nominal_text: str = "each state parameter at its nominal value",
    categories: Sequence[str] = (),
    registered: Mapping[str, Any] | None = None,
    stopping: Mapping[str, Any] | None = None,
) -> dict[str, Any]:
    """The experiment's summary.

    Args:
      states: columns of the states table (state_id, then the task's state parameters),
        each shape (n,).
      outcomes: per condition, the columns of its rollout table, each shape (n,).
      nominal: per condition, the success of the nominal state: the first classic mistake
        reports it alone.
      condition_parameters: per condition, the protocol parameters it sets, recorded beside
        its results.
      nominal_text: the nominal state in words (`Task.nominal_description`).
      categories: the task's failure categories in order (`Task.category_names()`).
      falsifier: the design's falsifier (treatment, baseline, statistic, threshold).
      analysis: the analysis config slice (n_resamples, confidence, seed, bands, first_k).
      sample_size: the design's sample-size plan (target_halfwidth); the summary says whether
        n met it.
      registered: the registration's record of the config (`registration.json`), if any: a
        comparison it did not plan is marked exploratory.
      stopping: a stopping rule's record (`mjtrial.stats.sequential.stopping_record`), if any: its
        test decides the falsifier, and the summary carries it (`stopping`).
    """
    confidence = float(analysis["confidence"])
    order = np.argsort(states["state_id"])
    state_ids = np.asarray(states["state_id"])[order]
    success: dict[str, np.ndarray] = {}
    for name, table in outcomes.items():
        ids = np.asarray(table["state_id"])
        sort = np.argsort(ids)
        if not np.array_equal(ids[sort], state_ids):
            raise ValueError(f"rollouts of {name!r}: state ids differ from the states table")
        success[name] = np.asarray(table["success"], dtype=bool)[sort]

    conditions = {}
    for name, table in outcomes.items():
        conditions[name] = {
            **condition_parameters[name],
            **rate_record(success[name], confidence=confidence),
            "unhealthy": int(unhealthy(table).sum()),
        }

    treatment, baseline = falsifier["treatment"], falsifier["baseline"]
    plan = planned_comparisons(analysis, falsifier, list(condition_parameters))
    records = [
        compare(success[c.treatment], success[c.baseline], comparison=c, analysis=analysis)
        for c in plan
    ]
    correct_family(records, exploratory(plan, registered))
    # the primary comparison also under the keys earlier summaries had (the manifest, `mjtrial
    # diff` and the studies read them)
    primary = records[0]
    paired = dict(primary["paired_difference"])

    bands = {
        parameter: band_table(
            band_values(states, parameter)[order], list(edges), success, confidence=confidence
        )
        for parameter, edges in analysis["bands"].items()
    }
    failures = {
        name: failure_counts(np.asarray(table["failure_category"], dtype=object), categories)
        for name, table in outcomes.items()
    }

    k = min(int(analysis["first_k"]), len(state_ids))
    mistakes = {
        "nominal_state": {
            "what": f"the nominal state alone ({nominal_text})",
            "conditions": {
                name: rate_record(np.array([nominal[name]]), confidence=confidence)
                for name in success
            },
        },
        "first_k": {
            "what": f"the first {k} states alone",
            "k": k,
            "conditions": {
                name: rate_record(s[:k], confidence=confidence) for name, s in success.items()
            },
        },
    }
    pooled = None
    if bands:  # the first band parameter is the one the pooled rates are read against
        first = next(iter(bands))
        pooled = {
            "what": f"pooled rates average over this {first} distribution; per-band rates "
            "beside them",
            f"{first}_bands": [{"band": b["band"], "n": b["n"]} for b in bands[first]],
        }
    return {
        "n_states": int(len(state_ids)),
        "confidence": confidence,
        "conditions": conditions,
        "paired_difference": paired,
        "discordant": dict(primary["table"]),
        "mcnemar": {k: primary["mcnemar"][k] for k in ("p_value", "method")},
        "comparisons": records,
        "multiple_comparisons": {
            "method": stats.HOLM_METHOD,
            "family": sum(not r["exploratory"] for r in records),
            "what": "McNemar p-values of the planned comparisons, adjusted together; an "
            "exploratory comparison's adjusted over every comparison tested; intervals are "
            "each comparison's own, unadjusted",
        },
        "bands": bands,
        "pooled_over": pooled,
        "failures": failures,
        "mistakes": mistakes,
        "falsifier": judge_falsifier(
            falsifier,
            paired,
            test=exact_test(primary, confidence),
            stopping=stopping,
            n_unhealthy=conditions[treatment]["unhealthy"] + conditions[baseline]["unhealthy"],
            n_episodes=2 * len(state_ids),
        ),
        "sample_size": sample_size_check(sample_size, len(state_ids), confidence=confidence),
        **({"stopping": dict(stopping)} if stopping is not None else {}),
    }


def sample_size_check(
    plan: Mapping[str, Any] | None, n: int, *, confidence: float
) -> dict[str, Any] | None:
    """Whether n met the design's plan: the worst-case episodes for its target half-width."""
    if plan is None:
        return None
    halfwidth = float(plan["target_halfwidth"])
    required = stats.episodes_for_halfwidth(halfwidth, 0.5, confidence)
    return {"target_halfwidth": halfwidth, "required": required, "n": n, "met": n >= required}


def _interval(rec: Mapping[str, Any]) -> str:
    if not rec["n"]:
        return "      (no states)"
    return (
        f"{rec['successes']:>5}/{rec['n']:<5} {rec['rate']:6.3f} "
        f"[{rec['wilson_low']:.3f}, {rec['wilson_high']:.3f}]"
    )


def comparison_lines(record: Mapping[str, Any]) -> list[str]:
    """One comparison of the summary as console lines: difference, interval, table, tests."""
    p, m = record["paired_difference"], record["mcnemar"]
    role = "primary (the falsifier's)" if record["primary"] else "secondary"
    if record["exploratory"]:
        role += ", EXPLORATORY (not in the registration)"
    how = p["method"]
    lines = [
        f"  {p['treatment']} - {p['baseline']} [{role}]: {p['estimate']:+.3f} "
        f"[{p['low']:+.3f}, {p['high']:+.3f}] ({how})"
    ]
    if record["bound"]:
        lines.append(f"    at its {record['bound']}: no discordant pair")
    lines.append("    Pairs: " + ", ".join(f"{k} {v}" for k, v in record["table"].items()))
    lines.append(f"    McNemar exact p = {m['p_value']:.3g}, Holm-adjusted p = {m['p_holm']:.3g}")
    return lines


def format_table(summary: Mapping[str, Any]) -> str:
    """The summary as the plain-text table printed to the console and the rule's log."""
    conf = f"{summary['confidence'] * 100:g}%"
    lines = [f"Success per condition (Wilson {conf} interval), n = {summary['n_states']} states"]
    for name, rec in summary["conditions"].items():
        setting = " ".join(f"{k} {v:g}" for k, v in condition_settings(rec).items())
        lines.append(f"  {name:<12} {setting}  {_interval(rec)}  unhealthy {rec['unhealthy']}")
    family = summary["multiple_comparisons"]
    lines.append(
        f"Planned comparisons ({len(summary['comparisons'])}; p-values adjusted by "
        f"{family['method']}, family of {family['family']})"
    )
    for c in summary["comparisons"]:
        lines += comparison_lines(c)
    for parameter, table in summary["bands"].items():
        lines.append(f"Success by {parameter} band")
        for band in table:
            for name, rec in band["conditions"].items():
                lines.append(f"  {band['band']:<16} {name:<12} {_interval(rec)}")
    lines.append("Failures by category")
    for name, counts in summary["failures"].items():
        lines.append(f"  {name:<12} " + ", ".join(f"{k} {v}" for k, v in counts.items()))
    lines.append("Classic evaluation mistakes, reproduced")
    for mistake in summary["mistakes"].values():
        lines.append(f"  {mistake['what']}:")
        for name, rec in mistake["conditions"].items():
            lines.append(f"    {name:<12} {_interval(rec)}")
    plan = summary.get("sample_size")
    if plan:
        met = "met" if plan["met"] else "NOT met"
        lines.append(
            f"Sample size: n = {plan['n']}, plan needs {plan['required']} for a half-width of "
            f"{plan['target_halfwidth']:g} at worst: {met}"
        )
    f = summary["falsifier"]
    lines.append(f"Falsifier: {f['verdict'].upper()}: {f['reason']}")
    return "\n".join(lines)
