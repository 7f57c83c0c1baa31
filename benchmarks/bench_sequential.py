"""Benchmark: stopping early with the registered stopping rule (`mjtrial.stats.sequential`), against
the fixed-N design it replaces. Every figure but the first is exact, not simulated.

1. **The gantry's question** (config/config.yaml: slow against fast lift): its N = 200 paired
   outcomes, read from the rollout tables of a built run in state order, replayed through the
   looks the pipeline makes (`mjtrial.stages.look`: one after every `--look-every` states, the
   same `stopping_record`). Goal: decided with at most 60 of the 200 pairs.
2. **The verdict's error under the null**: the exact chance that the rule's test rejects at
   some look (the last at N = 200 included), each state a treatment-only or baseline-only
   pair with probability discordance / 2 each (`sequential.operating_characteristics`), for
   looks after every state and after every `--look-every`. Goal: at most alpha.
3. **Power and mean N, calibrated threshold against 1/alpha, against a fixed N**: for
   alternatives (discordance, P(treatment wins a discordant pair)), the rule's exact power and
   mean N used (max N = 200) with the threshold calibrated to N and with Ville's 1/alpha; then
   the power of the one-sided exact McNemar test at the fixed N = 200, and the smallest fixed N
   whose test has the rule's power (the sum over the binomial number of discordant pairs of
   the exact test's conditional power).

    python benchmarks/bench_sequential.py --results /path/to/results/research_mode
    python benchmarks/bench_sequential.py --alpha 0.05 --out /tmp/sequential

The figures go to `--out` (`sequential_gantry.png`, `sequential_sample_size.png`). About 10 s.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
import pyarrow.parquet as pq  # noqa: E402
from scipy.stats import binom  # noqa: E402

from mjtrial import REPO_ROOT  # noqa: E402
from mjtrial.files.layout import Layout  # noqa: E402
from mjtrial.stats import sequential  # noqa: E402

ALPHA = 0.025  # the guide's: the one-sided level of a fixed-N verdict at confidence 0.95
MAX_N = 200
NULL_DISCORDANCE = (0.05, 0.2, 0.5, 1.0)
# (discordance, P(treatment wins a discordant pair)): the gantry's own (78 of 200 pairs
# discordant, all to the slow lift), rates 0.9 against 0.8 with independent outcomes, then
# smaller effects
ALTERNATIVES = ((0.39, 1.0), (0.26, 0.18 / 0.26), (0.3, 0.8), (0.4, 0.75), (0.2, 0.8), (0.5, 0.65))


def replay_gantry(results: Path, *, block: int, alpha: float) -> dict:
    """The looks the pipeline makes on the gantry's tables, in state order, up to the stop."""
    layout = Layout(results)
    slow = pq.read_table(layout.rollout_table("slow"))["success"].to_numpy()
    fast = pq.read_table(layout.rollout_table("fast"))["success"].to_numpy()
    rule = {"rule": "mixture_sprt", "alpha": alpha, "look_every": block, "max_n": len(slow)}
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


def fixed_power(n: int, discordance: float, win: float, alpha: float) -> float:
    """Exact power of the one-sided exact McNemar test at `alpha` with n pairs."""
    d = np.arange(n + 1)
    # the smallest count c with P(K >= c | d, 1/2) <= alpha (c = d + 1: never rejects)
    critical = binom.isf(alpha, d, 0.5) + 1
    critical = np.where(binom.sf(critical - 1, d, 0.5) <= alpha, critical, critical + 1)
    conditional = binom.sf(critical - 1, d, win)
    return float(np.sum(binom.pmf(d, n, discordance) * conditional))


def fixed_n_for(
    power: float, discordance: float, win: float, alpha: float, *, limit: int = 5000
) -> int | None:
    """The smallest n whose fixed-N test has at least `power` (None past `limit`)."""
    for n in range(1, limit + 1):
        if fixed_power(n, discordance, win, alpha) >= power:
            return n
    return None


def characteristics(discordance: float, win: float, *, every: int, threshold: float) -> dict:
    return sequential.operating_characteristics(
        max_n=MAX_N,
        look_every=every,
        p_win=discordance * win,
        p_loss=discordance * (1 - win),
        threshold=threshold,
    )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument(
        "--results",
        type=Path,
        default=REPO_ROOT / "results" / "research_mode",
        help="a built gantry run's results folder (its rollouts/slow.parquet, fast.parquet)",
    )
    parser.add_argument("--look-every", type=int, default=20, help="states between looks")
    parser.add_argument("--alpha", type=float, default=ALPHA, help="the rule's one-sided level")
    parser.add_argument("--out", type=Path, default=Path("/tmp/bench_sequential"))
    args = parser.parse_args()
    alpha, every = args.alpha, args.look_every
    args.out.mkdir(parents=True, exist_ok=True)
    calibrated = sequential.calibrated_threshold(MAX_N, alpha)
    threshold = calibrated["threshold"]
    print(
        f"threshold for N = {MAX_N}, alpha = {alpha:g}: {threshold:.4g} (1/alpha = "
        f"{1 / alpha:g}); exact error bound at it {calibrated['error_bound']:.5f}"
    )

    print(f"\n1. The gantry's question, looks after every {every} states")
    gantry = None
    if (args.results / "rollouts" / "slow.parquet").is_file():
        gantry = replay_gantry(args.results, block=every, alpha=alpha)
        everything = gantry["all_pairs"]
        print(
            f"   all {everything['n']} pairs: {everything['slow_only']} of "
            f"{everything['discordant']} discordant pairs succeed only under slow"
        )
        for look in gantry["looks"]:
            print(
                f"   look {look['look']}: n = {look['n']:>3}, {look['treatment_only']}/"
                f"{look['discordant']} discordant to slow, e-value {look['e_value']:.4g}"
            )
        goal = gantry["rejected"] and gantry["n_used"] <= 60
        print(
            f"   decided: {gantry['rejected']}, with {gantry['n_used']} of {everything['n']} "
            f"pairs (goal: at most 60): {'met' if goal else 'NOT met'}"
        )
    else:
        print(f"   no built run at {args.results}: skipped")

    print(f"\n2. The verdict's exact error under the null, N = {MAX_N}")
    for discordance in NULL_DISCORDANCE:
        rates = [
            characteristics(discordance, 0.5, every=e, threshold=threshold)["power"]
            for e in (1, every)
        ]
        print(
            f"   discordance {discordance:4.0%}: {rates[0]:.4f} looking after every state, "
            f"{rates[1]:.4f} after every {every}; "
            f"{'at most' if max(rates) <= alpha else 'ABOVE'} alpha = {alpha:g}"
        )

    print(
        f"\n3. Power and mean N (looks every {every}), calibrated threshold and 1/alpha, against"
        " a fixed-N one-sided exact McNemar test"
    )
    print(
        "   discordance  P(win)  power   E[N]   power(1/a)  E[N](1/a)  power(N=200)  fixed N "
        "of equal power"
    )
    rows = []
    for discordance, win in ALTERNATIVES:
        ours = characteristics(discordance, win, every=every, threshold=threshold)
        ville = characteristics(discordance, win, every=every, threshold=1 / alpha)
        fixed = fixed_power(MAX_N, discordance, win, alpha)
        # a power of 1 is matched at 0.99: no fixed N has power exactly 1
        equal = fixed_n_for(min(ours["power"], 0.99), discordance, win, alpha)
        print(
            f"   {discordance:10.0%}  {win:6.2f}  {ours['power']:5.3f}  {ours['mean_n']:5.1f}"
            f"  {ville['power']:10.3f}  {ville['mean_n']:9.1f}  {fixed:12.3f}  {equal!s:>7}"
        )
        rows.append((discordance, win, ours["power"], ours["mean_n"], equal))

    if gantry is not None:
        fig, ax = plt.subplots(figsize=(6, 3.5))
        looks = gantry["looks"]
        ax.semilogy([look["n"] for look in looks], [look["e_value"] for look in looks], "o-")
        ax.axhline(threshold, color="k", ls="--", lw=1, label=f"threshold {threshold:.3g}")
        ax.set(
            xlabel="states run", ylabel="e-value", title="The gantry's looks (slow against fast)"
        )
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
    print(f"\nfigures: {args.out}")


if __name__ == "__main__":
    main()
