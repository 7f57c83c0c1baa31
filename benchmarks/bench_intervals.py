"""Benchmark: the exact coverage of the paired interval the summary reports (Newcombe's hybrid
score interval, method 10) and of the percentile bootstrap it replaced, and the level of the
verdict's exact test, each summed over every paired table of n pairs (no simulation).

1. Newcombe's interval over a grid of rates (0.5 to 0.99), correlations of the two outcomes
   (0, 0.4, 0.8) and n = 20, 50, 100: the lowest coverage and where, the mean, and the lowest
   where both rates are 0.9 or more.
2. The interval reported before (the percentile bootstrap over pairs, 2,000 resamples, or
   Newcombe's where it was degenerate) against Newcombe's, near the ceiling (rates 0.95/0.90
   and 0.99/0.97, independent outcomes) at n = 20, 30 and 50.

    python benchmarks/bench_intervals.py

About a minute (the bootstrap is run once per table).
"""

from __future__ import annotations

import argparse
import math

import numpy as np
from scipy.stats import multinomial

from mjtrial import analysis, stats
from mjtrial.stats.comparisons import Comparison

RATES = (0.5, 0.6, 0.7, 0.9, 0.95, 0.99)
CORRELATIONS = (0.0, 0.4, 0.8)
SETTINGS = {"n_resamples": 2000, "confidence": 0.95, "seed": 5}


def tables(n: int) -> np.ndarray:
    """Every paired table of n pairs: (both, only treatment, only baseline, neither)."""
    return np.array(
        [
            (a, b, c, n - a - b - c)
            for b in range(n + 1)
            for c in range(n + 1 - b)
            for a in range(n + 1 - b - c)
        ]
    )


def cells(p1: float, p2: float, rho: float) -> np.ndarray | None:
    both = p1 * p2 + rho * math.sqrt(p1 * (1 - p1) * p2 * (1 - p2))
    out = np.array([both, p1 - both, p2 - both, 1 - p1 - p2 + both])
    return None if np.any(out < -1e-12) else np.clip(out, 0.0, 1.0)


def coverage(all_tables: np.ndarray, intervals: np.ndarray, probs: np.ndarray) -> float:
    truth = probs[1] - probs[2]
    inside = (intervals[:, 0] <= truth + 1e-12) & (intervals[:, 1] >= truth - 1e-12)
    return float(multinomial.pmf(all_tables[inside], int(all_tables[0].sum()), probs).sum())


def bootstrap_intervals(all_tables: np.ndarray) -> np.ndarray:
    plan = Comparison("slow", "fast", primary=True)
    out = []
    for a, b, c, d in all_tables:
        treatment = np.array([1] * (a + b) + [0] * (c + d), dtype=bool)
        baseline = np.array([1] * a + [0] * b + [1] * c + [0] * d, dtype=bool)
        record = analysis.compare(treatment, baseline, comparison=plan, analysis=SETTINGS)
        replaced = record["paired_difference"]["replaces"]
        if replaced["low"] == replaced["high"]:  # degenerate: Newcombe's, as reported then
            out.append(stats.newcombe_paired_interval(a, b, c, d)[1:])
        else:
            out.append((replaced["low"], replaced["high"]))
    return np.array(out)


def main() -> None:
    argparse.ArgumentParser(description=__doc__.split("\n")[0]).parse_args()
    print("1. Newcombe's interval (the summary's), exact coverage at 95 %")
    found = {}
    for n in (20, 50, 100):
        every = tables(n)
        intervals = np.array([stats.newcombe_paired_interval(*t)[1:] for t in every])
        for i, p1 in enumerate(RATES):
            for p2 in RATES[i:]:
                for rho in CORRELATIONS:
                    probs = cells(p1, p2, rho)
                    if probs is not None:
                        found[n, p1, p2, rho] = coverage(every, intervals, probs)
    worst = min(found, key=found.get)
    near = {k: v for k, v in found.items() if min(k[1], k[2]) >= 0.9}
    print(
        f"   {len(found)} settings: lowest {found[worst]:.3f} at n = {worst[0]}, rates "
        f"{worst[1]}/{worst[2]}, correlation {worst[3]}; mean {np.mean(list(found.values())):.3f}"
    )
    print(f"   both rates 0.9 or more: lowest {min(near.values()):.3f}")
    print("\n2. Near the ceiling, independent outcomes: bootstrap (as reported before) / Newcombe")
    for n in (20, 30, 50):
        every = tables(n)
        newcombe = np.array([stats.newcombe_paired_interval(*t)[1:] for t in every])
        for p1, p2 in ((0.95, 0.90), (0.99, 0.97)):
            probs = cells(p1, p2, 0.0)
            likely = multinomial.pmf(every, n, probs) > 1e-12
            boot = bootstrap_intervals(every[likely])
            print(
                f"   n = {n}, rates {p1}/{p2}: {coverage(every[likely], boot, probs):.3f} / "
                f"{coverage(every, newcombe, probs):.3f}"
            )


if __name__ == "__main__":
    main()
