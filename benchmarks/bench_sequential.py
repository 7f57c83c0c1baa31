"""Benchmark: stopping early with the registered stopping rule (`mjtrial.sequential`), against
the fixed-N design it replaces.

Three measurements, each printed and drawn:

1. **The gantry's question** (config/config.yaml: slow against fast lift): its N = 200 paired
   outcomes, read from the rollout tables of a built run in state order, replayed through the
   looks the pipeline makes (`mjtrial.stages.look`: one after each shard of `--block` states,
   the same `stopping_record`). Goal: decided with at most 60 of the 200 pairs at alpha = 0.05.
2. **The error rate under the null**: `--experiments` simulated paired experiments (N = 200,
   looks after each block) per discordance rate (5 %, 20 %, 50 %), each discordant pair won by
   the treatment with probability 1/2; the rate at which the e-value reached 1/alpha at any
   look, with its Monte Carlo standard error. Goal: at most alpha.
3. **Expected sample size against a fixed-N McNemar test of the same power**: for alternatives
   (discordance, P(treatment wins a discordant pair)), the stopping rule's power and mean N used
   (max N = 200) by simulation; then the smallest fixed N whose one-sided exact McNemar test at
   the same alpha has at least that power (at most 0.99), computed exactly (the sum over the
   binomial number of discordant pairs of the exact test's conditional power).

    python benchmarks/bench_sequential.py --results /path/to/results/research_mode
    python benchmarks/bench_sequential.py --experiments 2000 --out /tmp/sequential

The figures go to `--out` (`sequential_gantry.png`, `sequential_sample_size.png`). About 10 s.
"""

from __future__ import annotations

import argparse
import math
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
import pyarrow.parquet as pq  # noqa: E402
from scipy.stats import binom  # noqa: E402

from mjtrial import REPO_ROOT, sequential  # noqa: E402
from mjtrial.layout import Layout  # noqa: E402

ALPHA = 0.05
MAX_N = 200
NULL_DISCORDANCE = (0.05, 0.2, 0.5)
# (discordance, P(treatment wins a discordant pair)): the gantry's own (78 of 200 pairs
# discordant, all to the slow lift), then smaller effects
ALTERNATIVES = ((0.39, 1.0), (0.3, 0.8), (0.4, 0.75), (0.2, 0.8), (0.5, 0.65))


def replay_gantry(results: Path, *, block: int) -> dict:
    """The looks the pipeline makes on the gantry's tables, in state order, up to the stop."""
    layout = Layout(results)
    slow = pq.read_table(layout.rollout_table("slow"))["success"].to_numpy()
    fast = pq.read_table(layout.rollout_table("fast"))["success"].to_numpy()
    rule = {"rule": "mixture_sprt", "alpha": ALPHA, "block": block, "max_n": len(slow)}
    for stop in range(block, len(slow) + block, block):
        record = sequential.stopping_record(slow[:stop], fast[:stop], stopping=rule)
        if record["stopped"]:
            break
    full = sequential.discordant_wins(slow, fast)
    record["all_pairs"] = {
        "n": len(slow),
        "discordant": int(full.size),
        "slow_only": int(full.sum()),
    }
    return record


def simulate(
    rng: np.random.Generator, *, n: int, discordance: float, win: float, block: int
) -> tuple[np.ndarray, np.ndarray]:
    """Whether each simulated experiment rejected, and the states it used (max N if not)."""
    discordant = rng.random((n, MAX_N)) < discordance
    wins = discordant & (rng.random((n, MAX_N)) < win)
    looks = np.arange(block, MAX_N + block, block).clip(max=MAX_N)
    d = np.cumsum(discordant, axis=1)[:, looks - 1]
    k = np.cumsum(wins, axis=1)[:, looks - 1]
    crossed = sequential.log_e_value(k, d) >= math.log(1 / ALPHA)
    rejected = crossed.any(axis=1)
    used = np.where(rejected, looks[crossed.argmax(axis=1)], MAX_N)
    return rejected, used


def fixed_power(n: int, discordance: float, win: float) -> float:
    """Exact power of the one-sided exact McNemar test at ALPHA with n pairs."""
    d = np.arange(n + 1)
    # the smallest count c with P(K >= c | d, 1/2) <= ALPHA (c = d + 1: never rejects)
    critical = binom.isf(ALPHA, d, 0.5) + 1
    critical = np.where(binom.sf(critical - 1, d, 0.5) <= ALPHA, critical, critical + 1)
    conditional = binom.sf(critical - 1, d, win)
    return float(np.sum(binom.pmf(d, n, discordance) * conditional))


def fixed_n_for(power: float, discordance: float, win: float, *, limit: int = 5000) -> int | None:
    """The smallest n whose fixed-N test has at least `power` (None past `limit`)."""
    for n in range(1, limit + 1):
        if fixed_power(n, discordance, win) >= power:
            return n
    return None


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument(
        "--results",
        type=Path,
        default=REPO_ROOT / "results" / "research_mode",
        help="a built gantry run's results folder (its rollouts/slow.parquet, fast.parquet)",
    )
    parser.add_argument("--block", type=int, default=20, help="states per look (shard_size)")
    parser.add_argument("--experiments", type=int, default=10_000)
    parser.add_argument("--seed", type=int, default=20261127)
    parser.add_argument("--out", type=Path, default=Path("/tmp/bench_sequential"))
    args = parser.parse_args()
    rng = np.random.default_rng(args.seed)
    args.out.mkdir(parents=True, exist_ok=True)

    print(f"1. The gantry's question, looks after every {args.block} states, alpha = {ALPHA}")
    gantry = replay_gantry(args.results, block=args.block)
    every = gantry["all_pairs"]
    print(
        f"   all {every['n']} pairs: {every['slow_only']} of {every['discordant']} discordant "
        "pairs succeed only under slow"
    )
    for look in gantry["looks"]:
        print(
            f"   look {look['look']}: n = {look['n']:>3}, {look['treatment_only']}/"
            f"{look['discordant']} discordant to slow, e-value {look['e_value']:.4g}"
        )
    goal = gantry["rejected"] and gantry["n_used"] <= 60
    print(
        f"   decided: {gantry['rejected']}, with {gantry['n_used']} of {every['n']} pairs "
        f"(goal: at most 60): {'met' if goal else 'NOT met'}"
    )

    print(f"\n2. Error rate under the null, {args.experiments:,} experiments each, N = {MAX_N}")
    for discordance in NULL_DISCORDANCE:
        rejected, _ = simulate(
            rng, n=args.experiments, discordance=discordance, win=0.5, block=args.block
        )
        rate = rejected.mean()
        se = math.sqrt(rate * (1 - rate) / args.experiments) if rate else 0.0
        print(
            f"   discordance {discordance:4.0%}: rejection rate {rate:.4f} (MC s.e. {se:.4f}); "
            f"{'at most' if rate <= ALPHA else 'ABOVE'} alpha = {ALPHA}"
        )

    print(
        "\n3. Expected sample size against a fixed-N one-sided exact McNemar test of the same power"
    )
    print("   discordance  P(win)  power  E[N] (s.e.)    fixed N  saved")
    rows = []
    for discordance, win in ALTERNATIVES:
        rejected, used = simulate(
            rng, n=args.experiments, discordance=discordance, win=win, block=args.block
        )
        power, mean_n = rejected.mean(), used.mean()
        se = used.std(ddof=1) / math.sqrt(used.size)
        # a simulated power of 1 is matched at 0.99: no fixed N has power exactly 1
        fixed = fixed_n_for(min(power, 0.99), discordance, win)
        saved = f"{1 - mean_n / fixed:5.0%}" if fixed else "  -"
        print(
            f"   {discordance:10.0%}  {win:6.2f}  {power:5.3f}  {mean_n:6.1f} ({se:4.1f})"
            f"   {fixed!s:>7}  {saved}"
        )
        rows.append((discordance, win, power, mean_n, fixed))

    fig, ax = plt.subplots(figsize=(6, 3.5))
    ax.semilogy(
        [look["n"] for look in gantry["looks"]], [look["e_value"] for look in gantry["looks"]], "o-"
    )
    ax.axhline(1 / ALPHA, color="k", ls="--", lw=1, label=f"1/alpha = {1 / ALPHA:g}")
    ax.set(xlabel="states run", ylabel="e-value", title="The gantry's looks (slow against fast)")
    ax.legend()
    fig.tight_layout()
    fig.savefig(args.out / "sequential_gantry.png", dpi=120)
    fig, ax = plt.subplots(figsize=(6, 3.5))
    labels = [f"{d:.0%}, {w:.2f}" for d, w, *_ in rows]
    x = np.arange(len(rows))
    ax.bar(x - 0.2, [r[3] for r in rows], 0.4, label="stopping rule: mean N used")
    ax.bar(x + 0.2, [r[4] or 0 for r in rows], 0.4, label="fixed-N McNemar, same power")
    ax.set_xticks(x, labels)
    ax.set(xlabel="discordance, P(treatment wins a discordant pair)", ylabel="states")
    ax.legend()
    fig.tight_layout()
    fig.savefig(args.out / "sequential_sample_size.png", dpi=120)
    print(f"\nfigures: {args.out}/sequential_gantry.png, sequential_sample_size.png")


if __name__ == "__main__":
    main()
