"""Stopping early without p-hacking: an anytime-valid test on a paired design's discordant pairs.

The primary comparison runs every initial state under the treatment and the baseline. A pair in
which exactly one condition succeeds is *discordant*; under the null of no paired difference
(McNemar's null) each discordant pair favours the treatment with probability 1/2, whatever the
discordance rate, so the discordant pairs in state order are Bernoulli(1/2) trials.

The test is a mixture sequential probability ratio test (Robbins 1970): the likelihood ratio of
``p`` against ``1/2`` averaged over a prior on ``p``. With ``k`` treatment wins in ``d``
discordant pairs and a Beta(a, a) prior truncated to ``p > 1/2``::

    E_d = 2**d * integral_{1/2}^{1} p**k (1 - p)**(d - k) * 2 * p**(a-1) (1 - p)**(a-1) / B(a, a) dp
        = 2**(d + 1) * B(k + a, d - k + a) / B(a, a) * I_{1/2}(d - k + a, k + a)

(``I`` the regularized incomplete beta function). Each likelihood ratio is a nonnegative
martingale with mean 1 under the null, so their mixture is too (an e-process), and Ville's
inequality (Ville 1939) bounds ``P(sup_d E_d >= 1/alpha) <= alpha``: the type-I error stays at
most ``alpha`` however often the data are looked at and whenever the run stops. Looking only
after each block of states (a shard) can only lower it. This is the test-martingale view of
Howard, Ramdas, McAuliffe and Sekhon (2021), "Time-uniform, nonparametric, nonasymptotic
confidence sequences" (Ann. Statist. 49(2)), and a fixed-prior instance of the betting
e-processes of Waudby-Smith and Ramdas (2024, JRSS-B): the prior plays the part of the betting
fraction. STEP (Snyder et al., RSS 2025, arXiv 2503.10966) tests two policies' success rates
sequentially from unpaired trials; a simulator's common initial states make the trials paired,
and only the discordant ones carry information.

The test is one-sided, in the falsifier's direction: the hypothesis predicts the treatment
better than the baseline, and the design is refuted unless it is. Evidence the other way never
stops the run early; the experiment then runs to the registered maximum N and the fixed-N
analysis judges the falsifier as it would have without a stopping rule. A two-sided mixture
would spend half its prior on the direction no one predicted and need more pairs to stop.

Everything here is pure: numpy arrays in, numbers and JSON-ready records out.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Any

import numpy as np

__all__ = [
    "PRIOR",
    "RULES",
    "discordant_wins",
    "e_value",
    "e_values",
    "log_e_value",
    "stopping_record",
]

# The rules a config's `stopping.rule` may name.
RULES = ("mixture_sprt",)
# The mixture's prior: Beta(a, a) on p, truncated to p > 1/2 (a = 1: uniform on [1/2, 1]).
PRIOR = 1.0


def discordant_wins(treatment: Any, baseline: Any) -> np.ndarray:
    """The discordant pairs in state order: 1 where only the treatment succeeded, 0 where only
    the baseline did.

    Args:
        treatment: Success under the treatment, shape ``(n_pairs,)``, bool or 0/1.
        baseline: Success under the baseline on the same states, shape ``(n_pairs,)``.

    Returns:
        Shape ``(n_discordant,)``, int8.
    """
    a = np.asarray(treatment, dtype=bool)
    b = np.asarray(baseline, dtype=bool)
    if a.shape != b.shape or a.ndim != 1:
        raise ValueError(
            f"treatment and baseline: expected two (n_pairs,) arrays, got shapes {a.shape} "
            f"and {b.shape}"
        )
    discordant = a != b
    return a[discordant].astype(np.int8)


def log_e_value(wins: Any, discordant: Any, *, prior: float = PRIOR) -> np.ndarray:
    """The natural log of the one-sided mixture e-value after ``discordant`` pairs of which the
    treatment won ``wins`` (broadcast over arrays; ``-inf`` where the e-value underflows)."""
    # Imported here, as mjtrial.stats does: scipy.special costs 0.3 s in Snakemake's process.
    from scipy.special import betainc, betaln

    k = np.asarray(wins, dtype=float)
    d = np.asarray(discordant, dtype=float)
    if np.any(k < 0) or np.any(k > d):
        raise ValueError("wins: expected 0 <= wins <= discordant")
    with np.errstate(divide="ignore"):
        tail = np.log(betainc(d - k + prior, k + prior, 0.5))
    return (d + 1) * math.log(2.0) + betaln(k + prior, d - k + prior) - betaln(prior, prior) + tail


def e_value(wins: int, discordant: int, *, prior: float = PRIOR) -> float:
    """The one-sided mixture e-value after ``discordant`` pairs, ``wins`` the treatment's."""
    return float(np.exp(log_e_value(wins, discordant, prior=prior)))


def e_values(outcomes: Any, *, prior: float = PRIOR) -> np.ndarray:
    """The e-process along a sequence of discordant pairs.

    Args:
        outcomes: Shape ``(n_discordant,)``, 1 for a treatment win, 0 for a baseline win
            (`discordant_wins`).

    Returns:
        Shape ``(n_discordant,)``: the e-value after each pair.
    """
    x = np.asarray(outcomes, dtype=float)
    return np.exp(log_e_value(np.cumsum(x), np.arange(1, x.size + 1), prior=prior))


def stopping_record(
    treatment: Any, baseline: Any, *, stopping: Mapping[str, Any]
) -> dict[str, Any]:
    """The stopping rule applied to the pairs run so far: one look after each block of states.

    Args:
        treatment: Success under the falsifier's treatment, shape ``(n,)``, in state order.
        baseline: Success under its baseline on the same states, shape ``(n,)``.
        stopping: The rule (`config_slice("look", ...)`'s ``stopping``): ``rule``, ``alpha``,
            ``block`` (states per look, `rollout.shard_size`), ``max_n`` (`states.n`).

    Returns:
        The rule's settings, each look's states, discordant pairs, treatment wins and e-value,
        and ``stopped`` (the last look reached ``1/alpha``, or ``max_n``), ``stopped_at_look``,
        ``n_used`` and ``rejected`` (the null of no paired difference, in the falsifier's
        direction).
    """
    rule, alpha = stopping["rule"], float(stopping["alpha"])
    block, max_n = int(stopping["block"]), int(stopping["max_n"])
    if rule not in RULES:
        raise ValueError(f"stopping.rule: expected one of {list(RULES)}, got {rule!r}")
    a = np.asarray(treatment, dtype=bool)
    b = np.asarray(baseline, dtype=bool)
    discordant_wins(a, b)  # the shapes' check
    looks = []
    bound = math.log(1.0 / alpha)
    rejected_at = None
    for stop in range(block, a.size + block, block):
        n = min(stop, a.size)
        wins = discordant_wins(a[:n], b[:n])
        log_e = float(log_e_value(int(wins.sum()), wins.size))
        looks.append(
            {
                "look": len(looks),
                "n": n,
                "discordant": int(wins.size),
                "treatment_only": int(wins.sum()),
                "e_value": math.exp(log_e),
            }
        )
        if log_e >= bound and rejected_at is None:
            rejected_at = len(looks) - 1
    rejected = rejected_at is not None
    last = len(looks) - 1
    if rejected and rejected_at != last:
        raise ValueError(
            f"the pairs run go past the look that stopped: look {rejected_at} (n = "
            f"{looks[rejected_at]['n']}) reached 1/alpha, yet {a.size} states ran"
        )
    if a.size > max_n or (not rejected and a.size not in (0, max_n) and a.size % block):
        raise ValueError(f"{a.size} states ran: expected whole blocks of {block} up to {max_n}")
    return {
        "rule": rule,
        "alpha": alpha,
        "threshold": 1.0 / alpha,
        "block": block,
        "max_n": max_n,
        "prior": f"Beta({PRIOR:g}, {PRIOR:g}) on P(treatment wins a discordant pair), p > 1/2",
        "method": "one-sided mixture SPRT on the discordant pairs (Ville's inequality)",
        "looks": looks,
        "stopped": rejected or a.size >= max_n,
        "rejected": rejected,
        "stopped_at_look": last if (rejected or a.size >= max_n) and looks else None,
        "n_used": int(a.size),
    }
