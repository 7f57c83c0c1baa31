"""Simulator sensitivity: the preregistered falsifier judged again under each model variant.

Each variant (the nominal model first) runs the falsifier's two conditions on the same states;
its record holds each condition's rate, the falsifier's statistic with its interval and the
verdict. A variant with any unhealthy episode is `invalid`, never `refuted`: an unstable
simulator is not evidence against the hypothesis.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import numpy as np

from mjtrial import stats
from mjtrial.analysis import (
    VERDICT_INVALID,
    VERDICT_REFUTED,
    VERDICT_SURVIVES,
    judge_falsifier,
    rate_record,
    unhealthy,
)
from mjtrial.task import UNHEALTHY

NOMINAL = "nominal"


def paired_success(
    tables: Mapping[str, Mapping[str, np.ndarray]], *, source: str
) -> dict[str, np.ndarray]:
    """Each condition's success `(n,)`, in state-id order, checked to cover the same states."""
    success: dict[str, np.ndarray] = {}
    reference: np.ndarray | None = None
    for name, table in tables.items():
        ids = np.asarray(table["state_id"])
        order = np.argsort(ids, kind="stable")
        if reference is None:
            reference = ids[order]
        elif not np.array_equal(ids[order], reference):
            raise ValueError(f"{source}: rollouts of {name!r}: state ids differ from the others")
        success[name] = np.asarray(table["success"], dtype=bool)[order]
    return success


def variant_record(
    tables: Mapping[str, Mapping[str, np.ndarray]],
    *,
    overrides: Mapping[str, Any],
    model_sha256: str,
    falsifier: Mapping[str, Any],
    analysis: Mapping[str, Any],
    source: str = "variant",
) -> dict[str, Any]:
    """One variant's rates, falsifier statistic and verdict.

    Args:
      tables: per condition, the columns of its rollout table (`ROLLOUT_COLUMNS`), each `(n,)`;
        must hold the falsifier's treatment and baseline.
      overrides: the variant's overrides (`mjtrial.studies.variants`), recorded as given.
      model_sha256: the sha256 of the variant's compiled model (`physics.compiled_sha256`).
      falsifier: the design's falsifier (treatment, baseline, statistic, threshold).
      analysis: the analysis settings (confidence, n_resamples, seed).
      source: the variant's name, for error messages.
    """
    confidence = float(analysis["confidence"])
    success = paired_success(tables, source=source)
    treatment, baseline = falsifier["treatment"], falsifier["baseline"]
    for name in (treatment, baseline):
        if name not in success:
            raise ValueError(f"{source}: no rollouts of the falsifier's condition {name!r}")
    conditions = {
        name: {
            **rate_record(s, confidence=confidence),
            "unhealthy": int(unhealthy(tables[name]).sum()),
        }
        for name, s in success.items()
    }
    # the main analysis' interval and decision (`mjtrial.analysis.compare`, `judge_falsifier`)
    a, b = success[treatment], success[baseline]
    table = (int((a & b).sum()), int((a & ~b).sum()), int((~a & b).sum()), int((~a & ~b).sum()))
    _, low, high = stats.newcombe_paired_interval(*table, confidence=confidence)
    estimate = float(np.mean(a.astype(float) - b.astype(float)))  # as the analysis computes it
    paired = {"estimate": estimate, "low": low, "high": high}
    test = stats.mcnemar(a, b)
    n_unhealthy = sum(rec["unhealthy"] for rec in conditions.values())
    judged = judge_falsifier(
        falsifier,
        paired,
        test={
            "p_value": test.p_value,
            "treatment_only": test.only_a,
            "baseline_only": test.only_b,
            "alpha": 1.0 - confidence,
        },
        n_unhealthy=n_unhealthy,
        n_episodes=sum(rec["n"] for rec in conditions.values()),
    )
    verdict, reason = judged["verdict"], judged["reason"]
    return {
        "overrides": dict(overrides),
        "model_sha256": model_sha256,
        "conditions": conditions,
        "paired_difference": paired,
        "unhealthy": n_unhealthy,
        "verdict": verdict,
        "reason": reason,
    }


def summarize_sensitivity(
    variants: Mapping[str, Mapping[str, Any]],
    *,
    falsifier: Mapping[str, Any],
    analysis: Mapping[str, Any],
) -> dict[str, Any]:
    """The content of `analysis/sensitivity.json`.

    Args:
      variants: per variant name, in the order to report (`NOMINAL` first, from the built-in
        experiment's tables), a mapping with `tables` (per condition, the rollout table's
        columns, each `(n,)`), `overrides` and `model_sha256`.
      falsifier: the design's falsifier.
      analysis: confidence, n_resamples and seed (the main result's, so the nominal row equals
        the summary's paired difference).

    Returns the per-variant records and the count of variants (the nominal one excluded) under
    which the conclusion survives, is refuted, or cannot be judged (invalid).
    """
    records = {
        name: variant_record(
            v["tables"],
            overrides=v["overrides"],
            model_sha256=v["model_sha256"],
            falsifier=falsifier,
            analysis=analysis,
            source=f"variant {name!r}",
        )
        for name, v in variants.items()
    }
    others = [rec["verdict"] for name, rec in records.items() if name != NOMINAL]
    counts = {
        verdict: others.count(verdict)
        for verdict in (VERDICT_SURVIVES, VERDICT_REFUTED, VERDICT_INVALID)
    }
    return {
        "falsifier": dict(falsifier),
        "confidence": float(analysis["confidence"]),
        "paired_difference_method": stats.NEWCOMBE_METHOD,
        "unhealthy_definition": (
            "an episode with a MuJoCo warning, a non-finite state, or halted early "
            f"(failure category {UNHEALTHY!r})"
        ),
        "variants": records,
        "n_variants": len(others),
        "verdicts": counts,
        "survives_in": counts[VERDICT_SURVIVES],
    }


def flipped_episodes(
    nominal: Mapping[str, Mapping[str, np.ndarray]],
    variant: Mapping[str, Mapping[str, np.ndarray]],
) -> dict[str, Any]:
    """The states whose outcome under a variant differs from the nominal model's, per condition
    both ran: its count of the states compared, and each flipped episode's state id with its
    failure category in each run ("" where it succeeded), in state order."""
    out: dict[str, Any] = {"n_compared": 0, "episodes": []}
    for condition in (c for c in nominal if c in variant):
        a, b = nominal[condition], variant[condition]
        ids = np.intersect1d(a["state_id"], b["state_id"])
        ia, ib = np.searchsorted(a["state_id"], ids), np.searchsorted(b["state_id"], ids)
        out["n_compared"] += len(ids)
        for k in np.flatnonzero(a["success"][ia] != b["success"][ib]):
            out["episodes"].append(
                {
                    "condition": condition,
                    "state_id": int(ids[k]),
                    "nominal": _category(a, ia[k]),
                    "variant": _category(b, ib[k]),
                }
            )
    return out


def _category(table: Mapping[str, np.ndarray], row: int) -> str:
    return "" if table["success"][row] else str(table["failure_category"][row])
