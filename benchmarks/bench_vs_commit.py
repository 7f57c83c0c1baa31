"""Benchmark: the whole pipeline now against an earlier commit of this repository.

Is a change to the engine free? Both trees build the same experiment from nothing
(`snakemake -c2 --forceall`, the main target), each with its own code (`PYTHONPATH` set to its
`src`), in an order that flips every repeat; the figure is the median of the paired ratios of
wall time (earlier / now: above 1 means now is faster), with their range, and each side's
median wall time and the largest resident memory of any one of its processes.

    python benchmarks/bench_vs_commit.py --against 40e1774 --repeats 3
    python benchmarks/bench_vs_commit.py --against main --configfile config/cartpole_latency.yaml

The earlier commit is checked out into a temporary git worktree, removed at the end. Run it on
a quiet machine: both sides need the same two cores.
"""

from __future__ import annotations

import argparse
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import psutil

REPO = Path(__file__).resolve().parents[1]
SNAKEMAKE = str(Path(sys.executable).parent / "snakemake")


def build(tree: Path, configfile: str | None) -> tuple[float, int]:
    """Wall time (s) of a build from nothing, and the peak RSS (bytes) of its largest process,
    sampled every 50 ms."""
    args = [SNAKEMAKE, "-c2", "--forceall", "-q"]
    if configfile:
        args += ["--configfile", configfile]
    env = os.environ | {"PYTHONPATH": str(tree / "src"), "RERUN_ANALYTICS": "0"}
    start = time.perf_counter()
    proc = psutil.Popen(args, cwd=tree, env=env, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    peak = 0
    while proc.poll() is None:
        try:
            procs = [proc, *proc.children(recursive=True)]
            peak = max([peak, *(p.memory_info().rss for p in procs if p.is_running())])
        except psutil.Error:
            pass
        time.sleep(0.05)
    wall = time.perf_counter() - start
    if proc.returncode:
        raise SystemExit(f"{tree}: snakemake failed:\n{proc.stderr.read().decode()[-2000:]}")
    return wall, peak


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--against", required=True, help="the earlier commit (any git revision)")
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--configfile", help="an experiment's config (default: config/config.yaml)")
    args = parser.parse_args()
    with tempfile.TemporaryDirectory(prefix="mjtrial-bench-") as tmp:
        earlier = Path(tmp) / "earlier"
        subprocess.run(
            ["git", "worktree", "add", "--detach", str(earlier), args.against],
            cwd=REPO,
            check=True,
            capture_output=True,
        )
        try:
            runs: dict[str, list[tuple[float, int]]] = {"earlier": [], "now": []}
            trees = {"earlier": earlier, "now": REPO}
            for i in range(args.repeats):
                order = ("earlier", "now") if i % 2 == 0 else ("now", "earlier")
                for side in order:
                    runs[side].append(build(trees[side], args.configfile))
                    print(f"repeat {i + 1} {side:>7}: {runs[side][-1][0]:.2f} s", flush=True)
        finally:
            subprocess.run(
                ["git", "worktree", "remove", "--force", str(earlier)], cwd=REPO, check=False
            )
    ratios = [e[0] / n[0] for e, n in zip(runs["earlier"], runs["now"], strict=True)]
    print(f"experiment: {args.configfile or 'config/config.yaml'}; earlier = {args.against}")
    for side, rows in runs.items():
        wall = statistics.median(r[0] for r in rows)
        peak = max(r[1] for r in rows) / 2**20
        print(f"{side:>7}: median wall {wall:.2f} s, largest process peak RSS {peak:.0f} MB")
    print(
        f"speed now / earlier: {statistics.median(ratios):.3f}x median "
        f"(range {min(ratios):.3f}-{max(ratios):.3f}, {args.repeats} paired repeats)"
    )


if __name__ == "__main__":
    main()
