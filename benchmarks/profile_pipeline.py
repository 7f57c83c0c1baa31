"""Profile: where each second of the built-in experiment's N = 200 build goes.

Builds the gantry experiment (config/config.yaml) from nothing in a temporary copy of the
workflow (`snakemake -c2`), and the course's plain `mj_step` loop over the same 400 episodes in
the same command, alternating which runs first; then prints, from the last build:

- Snakemake's own start and DAG: a dry run's wall time (`snakemake -n`), and the time from the
  real run's start to its first job's;
- each job: when it started (s after Snakemake did), its wall and CPU time and, for a job in a
  process of its own, the share its interpreter's start and imports took (the log's
  `# stage entered:` line) ;
- inside each rollout job, its phases (the log's `# phases:` line, `mjtrial.sim.phases`): task and
  states, stamp, episode setup, physics (`mujoco.rollout`), recording (main thread, and the
  writer thread's own CPU, which overlaps the next batch's physics), measures + outcome, table
  + row hash, write table;
- the build's wall and CPU over the loop's (medians of the paired ratios).

    python benchmarks/profile_pipeline.py               # 2 alternating repeats
    python benchmarks/profile_pipeline.py --repeats 3
    python benchmarks/profile_pipeline.py --repeats 1 --n 4000   # at scale: 8 rollout jobs

Run it before and after a change (docs/architecture.md, "Checking a change's cost").
"""

from __future__ import annotations

import argparse
import os
import re
import shutil
import statistics
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))

import yaml  # noqa: E402
from bench_vs_plain_loop import copy_workflow, run_plain_loop, run_snakemake  # noqa: E402

from mjtrial import REPO_ROOT  # noqa: E402
from mjtrial.files.layout import CONFIG_FILE, RESULTS_DIR, Layout  # noqa: E402

RESOURCES = re.compile(r"# resources: wall ([\d.]+) s, cpu ([\d.]+) s(, in snakemake)?")
ENTERED = re.compile(r"# stage entered: wall ([\d.]+) s, cpu ([\d.]+) s")
PHASE = re.compile(r"([^,:]+?) ([\d.]+) s \(cpu ([\d.]+) s\)")


def jobs_of(work: Path, experiment: str, began: float) -> list[dict]:
    """Each job's log figures, in the order the jobs started."""
    jobs = []
    for log in Layout.of(experiment, base=work / RESULTS_DIR).logs_dir.glob("*.log"):
        text = log.read_text(encoding="utf-8")
        found = RESOURCES.search(text)
        if not found:
            continue
        wall, cpu = float(found[1]), float(found[2])
        job = {
            "name": log.stem,
            "wall": wall,
            "cpu": cpu,
            "in_process": bool(found[3]),
            "start": log.stat().st_mtime - wall - began,
        }
        entered = ENTERED.search(text)
        if entered:
            job["entered"] = (float(entered[1]), float(entered[2]))
        phases_line = next((x for x in text.splitlines() if x.startswith("# phases:")), None)
        if phases_line:
            job["phases"] = [
                (m[1].strip(), float(m[2]), float(m[3]))
                for m in PHASE.finditer(phases_line.removeprefix("# phases:"))
            ]
        jobs.append(job)
    return sorted(jobs, key=lambda j: j["start"])


def print_profile(dry: float, wall: float, cpu: float, jobs: list[dict]) -> None:
    first = min(j["start"] for j in jobs)
    last = max(j["start"] + j["wall"] for j in jobs)
    print(f"Snakemake: dry run (start + DAG) {dry:.2f} s; first job began at {first:.2f} s;")
    print(f"  last job ended at {last:.2f} s; Snakemake exited at {wall:.2f} s ({cpu:.1f} s CPU)")
    print(f"\n  {'job':<30} {'start':>6} {'wall':>6} {'CPU':>6}  start+imports (wall/CPU)")
    for j in jobs:
        where = "in snakemake" if j["in_process"] else ""
        if "entered" in j:
            where = f"{j['entered'][0]:.2f} / {j['entered'][1]:.2f} s"
        print(f"  {j['name']:<30} {j['start']:6.2f} {j['wall']:6.2f} {j['cpu']:6.2f}  {where}")
    for j in jobs:
        if "phases" not in j:
            continue
        print(f"\n  {j['name']}: wall {j['wall']:.2f} s, CPU {j['cpu']:.2f} s")
        if "entered" in j:
            print(
                f"    {'process start + imports':<28} {j['entered'][0]:6.3f} s  "
                f"cpu {j['entered'][1]:6.3f} s"
            )
        counted = j["entered"][0] if "entered" in j else 0.0
        for name, w, c in j["phases"]:
            print(f"    {name:<28} {w:6.3f} s  cpu {c:6.3f} s")
            if "writer thread" not in name:
                counted += w
        print(f"    {'rest (exit, logging, ...)':<28} {j['wall'] - counted:6.3f} s")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=2)
    parser.add_argument("--n", type=int, default=200, help="states (default: the config's 200)")
    args = parser.parse_args()
    os.environ.setdefault("RERUN_ANALYTICS", "0")
    config = yaml.safe_load((REPO_ROOT / CONFIG_FILE).read_text())
    runs: dict[str, list[tuple[float, float]]] = {"loop": [], "pipeline": [], "dry": []}
    profile = None
    for r in range(args.repeats):
        for what in ("loop", "pipeline") if r % 2 == 0 else ("pipeline", "loop"):
            if what == "loop":
                wall, cpu, _ = run_plain_loop(config, args.n)
                runs["loop"].append((wall, cpu))
                continue
            work = copy_workflow(args.n)
            dry = run_snakemake(work, "-n")[0]
            began = time.time()
            wall, cpu, _ = run_snakemake(work)
            runs["pipeline"].append((wall, cpu))
            runs["dry"].append((dry, 0.0))
            profile = (dry, wall, cpu, jobs_of(work, config["experiment"], began))
            shutil.rmtree(work)
        print(
            f"repeat {r + 1}: loop {runs['loop'][-1][0]:.2f} s wall {runs['loop'][-1][1]:.2f} s "
            f"CPU; build {runs['pipeline'][-1][0]:.2f} s wall {runs['pipeline'][-1][1]:.2f} s "
            "CPU",
            flush=True,
        )
    print("\nthe last build:")
    print_profile(*profile)
    pairs = list(zip(runs["pipeline"], runs["loop"], strict=True))
    wall_ratio = [p[0] / q[0] for p, q in pairs]
    cpu_ratio = [p[1] / q[1] for p, q in pairs]
    print(
        f"\nplain loop: {statistics.median(q[0] for _, q in pairs):.2f} s wall, "
        f"{statistics.median(q[1] for _, q in pairs):.2f} s CPU; build "
        f"{statistics.median(p[0] for p, _ in pairs):.2f} s wall, "
        f"{statistics.median(p[1] for p, _ in pairs):.2f} s CPU (medians)"
    )
    print(
        f"build / loop: wall {statistics.median(wall_ratio):.2f}x "
        f"({min(wall_ratio):.2f}-{max(wall_ratio):.2f}), CPU {statistics.median(cpu_ratio):.2f}x "
        f"({min(cpu_ratio):.2f}-{max(cpu_ratio):.2f}), {args.repeats} paired repeats"
    )


if __name__ == "__main__":
    main()
