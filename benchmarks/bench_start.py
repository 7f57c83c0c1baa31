"""Benchmark: what a Snakemake start costs (a dry run, `snakemake -n`) with the config check's
pass remembered (`mjtrial.config.passes`) against the same start with it forgotten (the folder
removed before the run), alternating which goes first in each repeat; medians of the CPU
seconds (the Snakemake process's, user + system) and of the paired ratios.

    python benchmarks/bench_start.py                                  # the built-in experiment
    python benchmarks/bench_start.py --configfile config/robosuite_lift.yaml --repeats 5

The runs are in a copy of the workflow in a temporary folder; the checkout is not touched.
"""

from __future__ import annotations

import argparse
import os
import resource
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from mjtrial import REPO_ROOT
from mjtrial.config.passes import CONFIG_CHECKS

COPIED = ("Snakefile", "workflow", "config", "models", "tasks", "profiles", "policies")


def dry_run(workdir: Path, args: list[str]) -> tuple[float, float]:
    """Wall and CPU seconds of one `snakemake -n` in `workdir` (CPU: its process and children)."""
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    t0 = time.perf_counter()
    subprocess.run(
        [str(Path(sys.executable).parent / "snakemake"), "-n", "-q", "-c2", *args],
        cwd=workdir,
        check=True,
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
    )
    wall = time.perf_counter() - t0
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    cpu = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
    return wall, cpu


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--configfile", help="an experiment's config (default: the built-in)")
    parser.add_argument("--repeats", type=int, default=5)
    args = parser.parse_args()
    snakemake_args = ["--configfile", args.configfile] if args.configfile else []
    with tempfile.TemporaryDirectory(prefix="mjtrial-bench-start-") as folder:
        workdir = Path(folder)
        for name in COPIED:  # as bench_memory.py copies it
            src = REPO_ROOT / name
            (shutil.copytree if src.is_dir() else shutil.copy)(src, workdir / name)
        dry_run(workdir, snakemake_args)  # compiles the model once for both (its MJB is kept)
        cpu: dict[str, list[float]] = {"remembered": [], "checked": []}
        ratios = []
        for repeat in range(args.repeats):
            order = ["checked", "remembered"] if repeat % 2 == 0 else ["remembered", "checked"]
            spent = {}
            for kind in order:
                if kind == "checked":  # forgotten: this start runs the check
                    shutil.rmtree(workdir / CONFIG_CHECKS, ignore_errors=True)
                elif not (workdir / CONFIG_CHECKS).exists():  # a pass to remember
                    dry_run(workdir, snakemake_args)
                _, spent[kind] = dry_run(workdir, snakemake_args)
                cpu[kind].append(spent[kind])
            ratios.append(spent["checked"] / spent["remembered"])
    which = args.configfile or "config/config.yaml"
    print(f"snakemake -n on {which}, {args.repeats} repeats, CPU seconds (median, range):")
    for kind, label in (("checked", "the check run"), ("remembered", "its pass remembered")):
        c = cpu[kind]
        print(f"  {label:22s} {statistics.median(c):6.2f} s  ({min(c):.2f}-{max(c):.2f})")
    print(
        f"  a remembered pass: {statistics.median(ratios):.2f}x less CPU per start "
        f"({min(ratios):.2f}-{max(ratios):.2f}); cores: {os.cpu_count()}"
    )


if __name__ == "__main__":
    main()
