"""Power before the run: what a paired design of N pairs can detect with McNemar's exact test.

Exact, not a normal approximation: of N pairs, D are discordant, D ~ Binomial(N, psi) with
psi the discordant share; given D, the pairs favouring the treatment are
Binomial(D, (psi + delta) / (2 psi)) with delta the paired difference (treatment minus
baseline success rate). The test rejects when its two-sided exact p (`stats.mcnemar`'s) is at
most alpha, so the power is the sum over D of P(D) times the rejection probability given D.
The minimum detectable difference is the smallest delta whose power reaches the target (found
by bisection: the power grows with delta at fixed psi); the pairs for a target difference are
the smallest N whose power reaches it, found by bisection and a look a few N below (the exact
power saw-tooths in N).
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import asdict, dataclass
from typing import Any

import numpy as np

POWER = 0.8
# Past this many pairs a plan is a typo, said in one line.
MAX_PAIRS = 100_000


@dataclass(frozen=True)
class PowerPlan:
    """A registered design's power: the planned pairs, the discordance it assumes and why,
    the minimum detectable difference at `power`, and the pairs for `target` when given."""

    pairs: int
    alpha: float
    power: float
    discordant: float
    source: str  # where `discordant` comes from: the pilot's tables, or the stated assumption
    detectable: float | None  # None: no difference up to the discordant share is detectable
    target: float | None = None
    pairs_for_target: int | None = None

    def record(self) -> dict[str, Any]:
        return asdict(self)


_LOWS: dict[float, list[int]] = {}
# How far below a crossing found by bisection an earlier one is looked for.
_SAWTOOTH = 16
# Rows of the binomial tables computed at once (bounds the memory at any N).
_CHUNK = 256


def _log_factorials(n: int) -> np.ndarray:
    """log(k!) for k in 0..n (numpy, not scipy: the Snakefile plans at registration, and
    scipy.stats alone takes longer to import than the whole plan takes to compute)."""
    return np.concatenate([[0.0], np.cumsum(np.log(np.arange(1, n + 1)))])


def _binomial_rows(first: int, stop: int, p: float, logf: np.ndarray) -> np.ndarray:
    """P(K = k) for K ~ Binomial(d, p), d in [first, stop) as rows, k in 0..stop-1 as columns
    (0 past d)."""
    d = np.arange(first, stop)[:, None]
    k = np.arange(stop)[None, :]
    inside = k <= d
    dk = np.where(inside, d - k, 0)
    log = logf[d] - logf[k] - logf[dk]
    with np.errstate(divide="ignore", invalid="ignore"):
        log = log + np.where(k > 0, k * np.log(p) if p > 0 else -np.inf, 0.0)
        log = log + np.where(dk > 0, dk * np.log1p(-p) if p < 1 else -np.inf, 0.0)
    return np.where(inside, np.exp(log), 0.0)


def _lower_critical(max_discordant: int, alpha: float) -> np.ndarray:
    """For each discordant count d in 0..max_discordant, the largest count k <= d / 2 at which
    the exact test rejects (it rejects at k and at d - k and beyond), -1 when it never does.
    Depends on d and alpha only, so it is kept across plans."""
    lows = _LOWS.setdefault(alpha, [-1])
    logf = _log_factorials(max_discordant + 1)
    for first in range(len(lows), max_discordant + 1, _CHUNK):
        stop = min(first + _CHUNK, max_discordant + 1)
        cdf = np.cumsum(_binomial_rows(first, stop, 0.5, logf), axis=1)
        for row, d in enumerate(range(first, stop)):
            p = np.minimum(1.0, 2.0 * cdf[row, : d // 2 + 1])
            reject = np.flatnonzero(p <= alpha * (1 + 1e-12))
            lows.append(int(reject.max()) if reject.size else -1)
    return np.asarray(lows[: max_discordant + 1])


def mcnemar_power(pairs: int, *, delta: float, discordant: float, alpha: float) -> float:
    """The exact power of the two-sided McNemar exact test at level `alpha` for `pairs` pairs,
    a paired difference `delta` and a discordant share `discordant` (|delta| <= discordant)."""
    if not 0 < discordant <= 1 or not abs(delta) <= discordant:
        raise ValueError(
            f"need 0 < discordant <= 1 and |difference| <= discordant, got {discordant:g}, "
            f"{delta:g}"
        )
    share = (discordant + delta) / (2 * discordant)
    low = _lower_critical(pairs, alpha)
    logf = _log_factorials(pairs + 1)
    weights = _binomial_rows(pairs, pairs + 1, discordant, logf)[0]
    total = 0.0
    for first in range(0, pairs + 1, _CHUNK):
        stop = min(first + _CHUNK, pairs + 1)
        rows = _binomial_rows(first, stop, share, logf)
        k = np.arange(stop)[None, :]
        d = np.arange(first, stop)[:, None]
        lo = low[first:stop, None]
        rejected = (lo >= 0) & ((k <= lo) | ((k >= d - lo) & (k <= d)))
        total += float(np.sum(weights[first:stop] * np.sum(rows * rejected, axis=1)))
    return float(min(1.0, total))


def detectable_difference(
    pairs: int, *, discordant: float, alpha: float, power: float = POWER
) -> float | None:
    """The smallest paired difference (to 1e-4) the test detects with `power`, or None when
    even delta = discordant (every discordant pair favouring the treatment) does not."""
    if mcnemar_power(pairs, delta=discordant, discordant=discordant, alpha=alpha) < power:
        return None
    low, high = 0.0, discordant
    while high - low > 1e-5:
        mid = (low + high) / 2
        if mcnemar_power(pairs, delta=mid, discordant=discordant, alpha=alpha) >= power:
            high = mid
        else:
            low = mid
    return math.ceil(high * 1e4) / 1e4


def pairs_needed(delta: float, *, discordant: float, alpha: float, power: float = POWER) -> int:
    """The smallest number of pairs whose exact power for `delta` reaches `power`."""
    if not 0 < abs(delta) <= discordant <= 1:
        raise ValueError(f"need 0 < |difference| <= discordant <= 1, got {delta}, {discordant}")

    def reaches(n: int) -> bool:
        return mcnemar_power(n, delta=delta, discordant=discordant, alpha=alpha) >= power

    high = 1
    while not reaches(high):
        high *= 2
        if high > MAX_PAIRS:
            raise ValueError(f"difference {delta:g} needs more than {MAX_PAIRS} pairs")
    low = high // 2  # not reaching (or 0); bisect to a crossing between the two
    while high - low > 1:
        mid = (low + high) // 2
        low, high = (low, mid) if reaches(mid) else (mid, high)
    # The exact power saw-tooths in n: an earlier crossing can lie just below this one.
    for n in range(max(1, high - _SAWTOOTH), high):
        if reaches(n):
            return n
    return high


def discordant_share(treatment: Any, baseline: Any) -> float:
    """The share of pairs whose outcomes differ (two boolean columns over the same states)."""
    a = np.asarray(treatment, dtype=bool)
    b = np.asarray(baseline, dtype=bool)
    return float(np.mean(a != b)) if a.size else 0.0


def power_plan(
    *,
    pairs: int,
    alpha: float,
    discordant: float,
    source: str,
    target: float | None = None,
    power: float = POWER,
) -> PowerPlan:
    """The plan `mjtrial plan` prints and the registration records."""
    if not 0 < discordant <= 1:
        raise ValueError(
            f"discordant share {discordant:g}: expected in (0, 1] (a pilot without any "
            "discordant pair says nothing of it: give --discordant)"
        )
    return PowerPlan(
        pairs=int(pairs),
        alpha=float(alpha),
        power=float(power),
        discordant=float(discordant),
        source=source,
        detectable=detectable_difference(pairs, discordant=discordant, alpha=alpha, power=power),
        target=target,
        pairs_for_target=None
        if target is None
        else pairs_needed(target, discordant=discordant, alpha=alpha, power=power),
    )


def plan_lines(plan: Mapping[str, Any]) -> list[str]:
    """The plan as a Markdown table (the report's section and `mjtrial plan`'s output)."""
    detect = plan["detectable"]
    rows = [
        ("pairs (N)", str(plan["pairs"])),
        ("test", f"McNemar's exact, two-sided, alpha {plan['alpha']:g}"),
        ("discordant share", f"{plan['discordant']:.3f} ({plan['source']})"),
        (
            f"minimum detectable difference at {plan['power']:.0%} power",
            f"{detect:+.3f}" if detect is not None else "none up to the discordant share",
        ),
    ]
    if plan.get("target") is not None:
        rows.append(
            (f"pairs for a difference of {plan['target']:+.3f}", str(plan["pairs_for_target"]))
        )
    return ["| | |", "| --- | --- |", *(f"| {k} | {v} |" for k, v in rows)]
