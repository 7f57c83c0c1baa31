"""Benchmark: the peak resident memory of every process of a clean `snakemake -c2`, against the
400 MB bar: Snakemake's own process (which runs the light jobs in threads) and each job that
runs in a process of its own (the rollouts).

    python benchmarks/bench_memory.py                 # the built-in experiment, N = 200
    python benchmarks/bench_memory.py --n 4000        # about 3 minutes on 2 cores
    python benchmarks/bench_memory.py --n 4000 --keep /tmp/run   # keep the run's folder
    python benchmarks/bench_memory.py --configfile config/robosuite_lift.yaml

A sampler reads every process's `VmHWM` (its peak resident memory, kept by the kernel) every
50 ms, so a process's peak is exact unless it was born and died between two samples; each job
process's own log (`# resources: ... peak rss`) gives its peak too, and each in-process job's
log gives Snakemake's resident memory when the job ended.
"""

from __future__ import annotations

import argparse
import re
import shutil
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

import psutil
import yaml

from mjtrial import REPO_ROOT
from mjtrial.files.layout import CONFIG_FILE, RESULTS_DIR, Layout

BAR_MB = 400
COPIED = ("Snakefile", "workflow", "config", "models", "tasks", "profiles")


def peak_mb(process: psutil.Process) -> float | None:
    """The process's peak resident memory so far (VmHWM), MB; None once it is gone."""
    try:
        with open(f"/proc/{process.pid}/status") as f:
            for line in f:
                if line.startswith("VmHWM:"):
                    return int(line.split()[1]) / 1024
    except OSError:
        return None
    return None


def describe(process: psutil.Process) -> str:
    """A job process by its script and log (Snakemake's `script:` runs a temporary copy)."""
    try:
        args = process.cmdline()
    except psutil.Error:
        return "?"
    words = (Path(a).name if "/" in a else a for a in args)
    return " ".join(" ".join(words).split())[:58]  # one line (a `python -c` spans several)


def sample(root: psutil.Process, peaks: dict[int, tuple[str, float]], stop: threading.Event):
    """Every 50 ms: the peak of `root` and of each of its descendants."""
    while not stop.is_set():
        try:
            processes = [root, *root.children(recursive=True)]
        except psutil.Error:
            processes = [root]
        for p in processes:
            mb = peak_mb(p)
            if mb is None:
                continue
            name = peaks[p.pid][0] if p.pid in peaks else describe(p)
            peaks[p.pid] = (name, max(mb, peaks.get(p.pid, ("", 0.0))[1]))
        stop.wait(0.05)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--n", type=int, default=200, help="states (default 200)")
    parser.add_argument("--cores", type=int, default=2)
    parser.add_argument(
        "--configfile", default=CONFIG_FILE, help=f"the experiment (default {CONFIG_FILE})"
    )
    parser.add_argument("--keep", type=Path, help="run in this folder and keep it")
    args = parser.parse_args()

    work = args.keep or Path(tempfile.mkdtemp(prefix="bench_memory_"))
    shutil.rmtree(work, ignore_errors=True)
    work.mkdir(parents=True)
    for name in COPIED:
        src = REPO_ROOT / name
        if src.exists():
            (shutil.copytree if src.is_dir() else shutil.copy)(src, work / name)
    cfg = yaml.safe_load((work / args.configfile).read_text())
    cfg["states"]["n"] = args.n
    (work / args.configfile).write_text(yaml.safe_dump(cfg, sort_keys=False))

    snakemake = str(Path(sys.executable).parent / "snakemake")
    peaks: dict[int, tuple[str, float]] = {}
    stop = threading.Event()
    started = time.perf_counter()
    proc = subprocess.Popen(
        [snakemake, f"-c{args.cores}", "--quiet", "all", "--configfile", args.configfile],
        cwd=work,
        stdout=subprocess.DEVNULL,
        stderr=subprocess.PIPE,
        text=True,
    )
    root = psutil.Process(proc.pid)
    sampler = threading.Thread(target=sample, args=(root, peaks, stop), daemon=True)
    sampler.start()
    _, err = proc.communicate()
    wall = time.perf_counter() - started
    stop.set()
    sampler.join()
    if proc.returncode:
        sys.exit(f"snakemake failed:\n{err[-2000:]}")

    main_peak = peaks[proc.pid][1]
    # Job processes; not Snakemake's forks caught before their `exec` (the same command line):
    # those share Snakemake's pages, copy-on-write, until the job's program replaces them.
    jobs = {pid: v for pid, v in peaks.items() if v[0] != peaks[proc.pid][0]}
    layout = Layout.of(cfg["experiment"], base=work / RESULTS_DIR)
    logged = {}  # a job's log -> its last `# resources:` line
    for log in sorted(layout.logs_dir.glob("*.log")):
        lines = [ln for ln in log.read_text().splitlines() if ln.startswith("# resources:")]
        if lines:
            logged[log.stem] = lines[-1]
    job_peaks = {
        stem: float(m.group(1))
        for stem, line in logged.items()
        if (m := re.search(r"peak rss (\d+) MB", line))
    }
    in_process = {
        stem: float(m.group(1))
        for stem, line in logged.items()
        if (m := re.search(r"\(rss (\d+) MB", line))
    }

    print(
        f"clean snakemake -c{args.cores} --configfile {args.configfile}, N = {args.n}: "
        f"{wall:.1f} s; bar {BAR_MB} MB a process"
    )
    print(f"\n{'process':<60} {'peak MB':>8}")
    print(f"{'snakemake (its own process, with the in-process jobs)':<60} {main_peak:8.0f}")
    for _pid, (name, mb) in sorted(jobs.items(), key=lambda kv: -kv[1][1])[:5]:
        print(f"  {name:<58} {mb:8.0f}")
    print(
        "\nfrom the jobs' logs: each job process's peak, and Snakemake's rss after each of its jobs"
    )
    for stem, mb in sorted(job_peaks.items(), key=lambda kv: -kv[1])[:6]:
        print(f"  {stem:<58} {mb:8.0f}  (peak)")
    for stem, mb in in_process.items():
        print(f"  {stem:<58} {mb:8.0f}  (snakemake's rss after it)")
    largest_job = max([mb for _, mb in jobs.values()] + list(job_peaks.values()), default=0.0)
    verdict = "within" if max(main_peak, largest_job) <= BAR_MB else "OVER"
    print(
        f"\npeak of snakemake's process: {main_peak:.0f} MB; of the largest job process: "
        f"{largest_job:.0f} MB; bar {BAR_MB} MB: {verdict}"
    )
    if not args.keep:
        shutil.rmtree(work, ignore_errors=True)


if __name__ == "__main__":
    main()
