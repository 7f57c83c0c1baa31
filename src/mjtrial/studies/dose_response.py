"""Dose-response: success against one protocol parameter (a duration, a gain, a latency).

Every swept value runs on the same initial states, so the outcomes are paired (clustered by
state) and every comparison here respects that: the trend's standard errors are clustered by
state, and each value is compared with the reference by paired difference and McNemar's test.
"""

from __future__ import annotations

import warnings
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np

from mjtrial import stats
from mjtrial.analysis import band_index, band_labels, band_values, rate_record
from mjtrial.studies.sensitivity import paired_success

TREND_METHOD = (
    "logistic regression of success on {x} (statsmodels GLM, Binomial, logit link) with "
    "state-clustered sandwich standard errors (small-sample factor G/(G-1) (N-1)/(N-K)), "
    "normal-theory interval"
)
# A sweep with a value at or below zero (a latency of 0 s) is fitted on the value itself.
SCALES = ("log", "linear")


def sweep_scale(values: Sequence[float]) -> str:
    """`log` when every swept value is positive (a duration), else `linear`."""
    return "log" if min(values) > 0 else "linear"


HOLM_METHOD = "Holm step-down over the non-reference values (statsmodels multipletests)"


def trend(
    value: np.ndarray,
    success: np.ndarray,
    groups: np.ndarray,
    *,
    confidence: float,
    scale: str = "log",
) -> dict[str, Any]:
    """Slope of the log-odds of success per unit log(value), with its clustered interval; on
    the `linear` scale, per unit value, with the odds ratio over the swept range instead of
    per doubling.

    Args:
      value: the swept value of each episode, `(N,)`, positive on the log scale.
      success: each episode's outcome, `(N,)` booleans.
      groups: each episode's state id (the cluster), `(N,)`.
      confidence: two-sided confidence of the interval.

    Returns slope, its standard error, interval and p-value (Wald, two-sided), the odds ratio
    per doubling of the value (exp(slope ln 2)) with its interval, and the method. When the
    fit has no finite estimate (every outcome the same, or outcomes separated by the value, as
    small samples can be), every number is None and `not_estimable` says why.
    """
    # Imported here: statsmodels costs every process that imports this module (verify, the
    # studies' Snakemake process) two seconds, and most never fit a trend.
    import statsmodels.api as sm

    value = np.asarray(value, dtype=float)
    log = scale == "log"
    x = sm.add_constant(np.log(value) if log else value)
    y = np.asarray(success, dtype=float)
    base = {
        "n_episodes": int(x.shape[0]),
        "n_clusters": int(np.unique(groups).size),
        "method": TREND_METHOD.format(x="log(value)" if log else "the value"),
    }
    slope_key = "slope_log_odds_per_log_value" if log else "slope_log_odds_per_unit_value"
    ratio_key = "odds_ratio_per_doubling" if log else "odds_ratio_over_range"
    span = np.log(2) if log else float(value.max() - value.min())
    with warnings.catch_warnings():  # separation shows below as non-finite numbers
        warnings.simplefilter("ignore")
        fit = sm.GLM(y, x, family=sm.families.Binomial()).fit(
            cov_type="cluster", cov_kwds={"groups": np.asarray(groups)}
        )
        low, high = fit.conf_int(alpha=1.0 - confidence)[1]
    numbers = [fit.params[1], fit.bse[1], low, high, fit.pvalues[1]]
    if y.min() == y.max() or not np.all(np.isfinite(numbers)) or fit.bse[1] > 1e3:
        keys = [
            slope_key,
            *"standard_error low high p_value intercept".split(),
            *(f"{ratio_key}{end}" for end in ("", "_low", "_high")),
        ]
        return {
            **dict.fromkeys(keys),
            "not_estimable": "the outcomes are all alike or separated by the value",
            **base,
        }
    slope = float(fit.params[1])
    return {
        slope_key: slope,
        "standard_error": float(fit.bse[1]),
        "low": float(low),
        "high": float(high),
        "p_value": float(fit.pvalues[1]),
        "intercept": float(fit.params[0]),
        ratio_key: float(np.exp(slope * span)),
        f"{ratio_key}_low": float(np.exp(low * span)),
        f"{ratio_key}_high": float(np.exp(high * span)),
        **base,
    }


def summarize_dose_response(
    tables: Mapping[float, Mapping[str, np.ndarray]],
    *,
    parameter: str,
    states: Mapping[str, np.ndarray],
    band_parameter: str,
    band_edges: Sequence[float],
    analysis: Mapping[str, Any],
    margin: float,
    reference: float | None = None,
    toward: str | None = None,
    units: Mapping[str, str] | None = None,
) -> dict[str, Any]:
    """The content of `analysis/dose_response.json`.

    Args:
      tables: per swept value (e.g. a duration, s), the columns of its rollout table
        (`ROLLOUT_COLUMNS`), each `(n,)`, all on the same states.
      parameter: the swept protocol parameter's name (e.g. "push_time"), recorded.
      states: the states table's columns (state_id and the state parameters), each `(n,)`.
      band_parameter: the state parameter whose bands split each value's rate (the first of
        `analysis.bands`; `abs_<name>` for its magnitude).
      band_edges: its band edges.
      analysis: confidence, n_resamples and seed (the main result's).
      margin: the success margin of `furthest_within_margin`, in (0, 1).
      reference: the value every other is compared with; the largest if None.
      toward: "smaller" or "larger", the direction in which values cost (a longer motion takes
        time; a longer latency is what is tolerated); if None, away from the reference, which
        must then be the smallest or the largest value.
      units: the swept parameter's and the band parameter's units, by name (recorded for the
        report's words).

    A value is within the margin when its paired difference success(v) - success(reference)
    has its bootstrap interval's lower bound at or above -margin: its success is shown, at the
    stated confidence, to be at most `margin` below the reference's (a non-inferiority
    criterion; the reference itself always qualifies). `furthest_within_margin` is the value
    furthest from the reference toward `toward` that is within the margin together with every
    value between it and the reference: "down to a 0.45 s motion", "up to 20 ms of latency", each
    step of the way shown to cost less than the margin. `values_within_margin` lists every value
    that qualifies on its own.
    """
    values = sorted(float(v) for v in tables)
    if len(values) < 3:
        raise ValueError(f"sweep of {parameter}: expected at least 3 values, got {len(values)}")
    if not 0.0 < margin < 1.0:
        raise ValueError(f"margin: expected a number in (0, 1), got {margin}")
    reference = max(values) if reference is None else float(reference)
    if reference not in values:
        raise ValueError(f"reference: {reference:g} is not a swept value of {parameter}")
    if toward is None:
        if min(values) < reference < max(values):
            raise ValueError(f"toward: expected smaller or larger; {reference:g} lies inside")
        toward = "smaller" if reference == max(values) else "larger"
    if toward not in ("smaller", "larger"):
        raise ValueError(f"toward: expected smaller or larger, got {toward!r}")
    confidence = float(analysis["confidence"])
    by_value = {float(v): t for v, t in tables.items()}
    success = paired_success(
        {f"{v:g}": by_value[v] for v in values}, source=f"sweep of {parameter}"
    )
    state_ids = np.sort(np.asarray(next(iter(by_value.values()))["state_id"]))
    order = np.argsort(np.asarray(states["state_id"]), kind="stable")
    if not np.array_equal(np.asarray(states["state_id"])[order], state_ids):
        raise ValueError(f"sweep of {parameter}: state ids differ from the states table")
    band = band_index(band_values(states, band_parameter)[order], band_edges)
    labels = band_labels(band_edges)

    rows = []
    for v in values:
        s = success[f"{v:g}"]
        rows.append(
            {
                parameter: v,
                **rate_record(s, confidence=confidence),
                "bands": [
                    {
                        "band": label,
                        "low": band_edges[i],
                        "high": band_edges[i + 1],
                        **rate_record(s[band == i], confidence=confidence),
                    }
                    for i, label in enumerate(labels)
                ],
            }
        )

    ref = success[f"{reference:g}"]
    comparisons = []
    for v in values:
        if v == reference:
            continue
        s = success[f"{v:g}"]
        estimate, low, high = stats.paired_difference_ci(
            s.astype(float),
            ref.astype(float),
            n_resamples=int(analysis["n_resamples"]),
            confidence=confidence,
            seed=int(analysis["seed"]),
        )
        test = stats.mcnemar(s, ref)
        comparisons.append(
            {
                parameter: v,
                "estimate": estimate,
                "low": low,
                "high": high,
                f"only_{parameter}": test.only_a,
                "only_reference": test.only_b,
                "p_value": test.p_value,
                "within_margin": low >= -margin,
            }
        )
    from statsmodels.stats.multitest import multipletests  # imported here, as above

    _, adjusted, _, _ = multipletests(
        [c["p_value"] for c in comparisons], alpha=1.0 - confidence, method="holm"
    )
    for c, p in zip(comparisons, adjusted, strict=True):
        c["p_holm"] = float(p)
        c["significant"] = bool(p <= 1.0 - confidence)

    qualifying = [c[parameter] for c in comparisons if c["within_margin"]] + [reference]
    furthest = reference
    # from the reference outward, while every step stays within the margin
    outward = [v for v in values if (v < reference if toward == "smaller" else v > reference)]
    for v in sorted(outward, reverse=toward == "smaller"):
        if v not in qualifying:
            break
        furthest = v
    extreme = "smallest" if toward == "smaller" else "largest"
    n = len(state_ids)
    return {
        "parameter": parameter,
        "values": values,
        "n_states": n,
        "confidence": confidence,
        "unit": (units or {}).get(parameter, ""),
        "band_parameter": band_parameter,
        "band_unit": (units or {}).get(band_parameter, ""),
        "band_edges": list(band_edges),
        "per_value": rows,
        "trend": trend(
            np.repeat(values, n),
            np.concatenate([success[f"{v:g}"] for v in values]),
            np.tile(state_ids, len(values)),
            confidence=confidence,
            scale=sweep_scale(values),
        ),
        "scale": sweep_scale(values),
        "reference": reference,
        "comparisons": comparisons,
        "comparison_method": {
            "difference": f"{stats.BOOTSTRAP_METHOD} over pairs, value minus reference",
            "test": stats.MCNEMAR_METHOD,
            "adjustment": HOLM_METHOD,
            "n_resamples": int(analysis["n_resamples"]),
            "seed": int(analysis["seed"]),
        },
        "margin": margin,
        "toward": toward,
        "furthest_within_margin": furthest,
        "values_within_margin": sorted(qualifying),
        "within_margin_criterion": (
            f"the {extreme} {parameter} such that it and every swept value between it and "
            f"{reference:g} have a paired difference to {reference:g} whose {confidence:.0%} "
            f"interval's lower bound is at or above -{margin:g}"
        ),
    }
