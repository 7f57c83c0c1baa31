"""Benchmark: clean `snakemake -c2` runs against the plain loop a researcher writes without it.

The baseline is the course's worked example: one `MjData` per episode, `mj_step` in a Python
loop, the controls set between holds, nothing recorded per step, every state under every
condition, one process. The pipeline does far more (a recording of every episode, the failure
taxonomy, the analysis with its bootstrap, figures, the report, stamps, the seal), so these
ratios are the price of all that, measured against what a competent user would write instead.

    python benchmarks/bench_vs_plain_loop.py            # every figure (about 15 minutes)
    python benchmarks/bench_vs_plain_loop.py --quick    # N = 200 and the logging share only
    python benchmarks/bench_vs_plain_loop.py --slurm    # also the SLURM round trip (root, apt)

It prints, in one run:
- N = 200 (the built-in experiment): wall and CPU time of a clean run over the loop's, from
  `--repeats` repeats that run the loop and the pipeline back to back, in an order that flips
  every repeat (medians of the paired ratios, with their range), and each job's own wall time,
  CPU time and memory from its log;
- the share of the rollout stage's CPU (every thread) spent on replay logging: the stage run on
  the same shard with and without its recordings, alternating;
- N = 2,000 and N = `--scale-n` (20,000): one clean run each, its wall time over the loop's
  (the loop timed on 200 states, 400 episodes, and scaled linearly: it is linear), and the
  peak resident memory of the largest process (Snakemake's own, which runs every job);
- with `--slurm`, whether `tests/cluster/run_slurm_test.sh` passes, and its time.

The environment should not hold the SLURM executor plugin (the optional extra `.[slurm]`):
wherever SLURM's client is installed but no controller answers, its import waits about 9 s.
"""

from __future__ import annotations

import argparse
import copy
import os
import re
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

# The gantry task's own modules (protocol, reference stepper) as the package `gantry_lift`.
sys.path.append(str(Path(__file__).resolve().parents[1] / "tasks"))

import mujoco
import numpy as np
import pyarrow.parquet as pq
import yaml
from gantry_lift.protocol import CTRL_GRIPPER, CTRL_Z, PROTOCOL, hold_steps
from gantry_lift.states import STATE_PARAMETERS, states_from_table

from mjtrial import REPO_ROOT
from mjtrial.design.states import generate_initial_states
from mjtrial.files.layout import CONFIG_FILE, RESULTS_DIR, Layout
from mjtrial.sim.physics import load_model
from mjtrial.stages.rollout import run_shard
from mjtrial.stages.stamping import config_slice
from mjtrial.stages.states import build_states

WORKFLOW = ("Snakefile", "workflow", "config", "models", "tasks", "profiles")
RESOURCES = re.compile(r"# resources: wall ([\d.]+) s, cpu ([\d.]+) s")


def plain_loop_episode(model: mujoco.MjModel, state, lift_time: float) -> float:
    """One episode as the course writes it: returns the cube's final height (m)."""
    p = PROTOCOL
    m = copy.copy(model)
    d = mujoco.MjData(m)
    cube = m.body("cube").id
    m.body_mass[cube] = state.mass
    mujoco.mj_setConst(m, d)
    mujoco.mj_resetDataKeyframe(m, d, 0)
    adr = m.jnt_qposadr[m.body_jntadr[cube]]
    d.qpos[adr : adr + 3] = (p.home_x + state.dx, state.dy, p.cube_z)
    d.qpos[adr + 3 : adr + 7] = (np.cos(state.yaw / 2), 0, 0, np.sin(state.yaw / 2))
    d.ctrl[:] = (p.home_x, 0.0, p.z_up, p.gripper_open)

    def hold(duration: float) -> None:
        for _ in range(hold_steps(duration, m.opt.timestep)):
            mujoco.mj_step(m, d)

    hold(p.settle_time)
    for k in range(p.descend_segments):
        d.ctrl[CTRL_Z] = p.z_down * (k + 1) / p.descend_segments
        hold(p.segment_time)
    hold(p.pre_close_time)
    d.ctrl[CTRL_GRIPPER] = p.gripper_closed
    hold(p.close_time)
    steps = max(1, round(lift_time / p.segment_time))
    for k in range(steps):
        d.ctrl[CTRL_Z] = p.z_down + (p.z_up - p.z_down) * (k + 1) / steps
        hold(lift_time / steps)
    hold(p.hold_time)
    return float(d.qpos[adr + 2])


def run_plain_loop(config: dict, n: int) -> tuple[float, float, dict[str, np.ndarray]]:
    """(wall s, CPU s, final heights per condition) of the loop over n states."""
    model = load_model(REPO_ROOT / config["model"])
    s = config["states"]
    states = states_from_table(
        generate_initial_states(
            seed=s["seed"], n=n, ranges=s["ranges"], parameters=STATE_PARAMETERS
        )
    )
    t0, c0 = time.perf_counter(), time.process_time()
    heights = {
        name: np.array([plain_loop_episode(model, st, c["lift_time"]) for st in states])
        for name, c in config["conditions"].items()
    }
    return time.perf_counter() - t0, time.process_time() - c0, heights


def copy_workflow(n: int) -> Path:
    """A fresh temporary copy of the workflow, its experiment set to n states."""
    work = Path(tempfile.mkdtemp(prefix="mjtrial-bench-"))
    for name in WORKFLOW:
        src = REPO_ROOT / name
        (shutil.copytree if src.is_dir() else shutil.copy)(src, work / name)
    if n != 200:
        path = work / CONFIG_FILE
        cfg = yaml.safe_load(path.read_text())
        cfg["states"]["n"] = n
        path.write_text(yaml.safe_dump(cfg, sort_keys=False))
    return work


def run_snakemake(work: Path, *args: str) -> tuple[float, float, float]:
    """`snakemake -c2 --quiet *args` in `work`: (wall s, CPU s of every process, peak resident
    MB of the largest process)."""
    snakemake = str(Path(sys.executable).parent / "snakemake")
    with open(work / "snakemake.out", "w") as out:
        t0 = time.perf_counter()
        proc = subprocess.Popen(
            [snakemake, "-c2", "--quiet", *args], cwd=work, stdout=out, stderr=out
        )
        # wait4: this run's own CPU time and peak memory, its descendants included
        _, status, usage = os.wait4(proc.pid, 0)
        wall = time.perf_counter() - t0
    if os.waitstatus_to_exitcode(status):
        sys.exit(f"snakemake failed:\n{(work / 'snakemake.out').read_text()[-2000:]}")
    return wall, usage.ru_utime + usage.ru_stime, usage.ru_maxrss / 1024


def run_pipeline(n: int) -> tuple[float, float, float, Path]:
    """A clean `snakemake -c2` on n states in a fresh copy of the workflow: (wall s, CPU s of
    every process, peak resident MB of the largest process, its folder)."""
    work = copy_workflow(n)
    return (*run_snakemake(work), work)


def job_resources(work: Path, experiment: str) -> dict[str, tuple[float, float]]:
    """Each job's (wall s, CPU s) from the `# resources:` line of its log."""
    found = {}
    for log in sorted(Layout.of(experiment, base=work / RESULTS_DIR).logs_dir.glob("*.log")):
        match = RESOURCES.search(log.read_text(encoding="utf-8"))
        if match:
            found[log.stem] = (float(match[1]), float(match[2]))
    return found


def logging_share(config: dict, n: int, repeats: int) -> list[float]:
    """Per repeat, the share of the rollout stage's CPU (every thread of this process) spent on
    replay logging: each condition's stage run on n states with and without its recordings, back
    to back, in an order that flips every repeat."""
    shares = []
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        states = tmp / "states.parquet"
        build_states(
            states_slice={**config_slice("states", config), "n": n},
            output=states,
            repo_root=REPO_ROOT,
        )

        def stage(recorded: bool) -> float:
            c0 = time.process_time()
            for name in config["conditions"]:
                folder = tmp / f"{name}-recordings"
                shutil.rmtree(folder, ignore_errors=True)
                run_shard(
                    condition_slice=config_slice("rollout", config, condition=name),
                    states_path=states,
                    model_file=REPO_ROOT / config["model"],
                    first=0,
                    stop=n,
                    output_table=tmp / f"{name}.parquet",
                    output_recording=folder if recorded else None,
                    nthread=1,
                    rule=f"rollout:{name}",
                )
            return time.process_time() - c0

        for r in range(repeats):
            cpu = {}
            for recorded in (True, False) if r % 2 == 0 else (False, True):
                cpu[recorded] = stage(recorded)
            shares.append((cpu[True] - cpu[False]) / cpu[True])
    return shares


def median_range(values: list[float], fmt: str = ".2f") -> str:
    return f"{statistics.median(values):{fmt}} ({min(values):{fmt}} to {max(values):{fmt}})"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=3, help="repeats at N = 200")
    parser.add_argument("--scale-n", type=int, default=20_000, help="the large run's states")
    parser.add_argument("--quick", action="store_true", help="skip the N = 2,000 and large runs")
    parser.add_argument("--slurm", action="store_true", help="also the SLURM round trip")
    args = parser.parse_args()
    os.environ.setdefault("RERUN_ANALYTICS", "0")
    config = yaml.safe_load((REPO_ROOT / CONFIG_FILE).read_text())
    n_conditions = len(config["conditions"])
    rows: list[tuple[str, str, str]] = []

    # N = 200, paired with the loop, alternating.
    walls, cpus, loop_walls, loop_cpus = [], [], [], []
    jobs: dict[str, tuple[float, float]] = {}
    for r in range(args.repeats):
        for what in ("loop", "pipeline") if r % 2 == 0 else ("pipeline", "loop"):
            if what == "loop":
                loop_wall, loop_cpu, heights = run_plain_loop(config, 200)
            else:
                pipe_wall, pipe_cpu, peak_200, work = run_pipeline(200)
        for name, h in heights.items():  # the pipeline's outcomes are the loop's, bit for bit
            table = pq.read_table(
                Layout.of(config["experiment"], base=work / RESULTS_DIR).rollout_table(name)
            )
            assert np.array_equal(table.column("final_height").to_numpy(), h), name
        jobs = jobs or job_resources(work, config["experiment"])
        shutil.rmtree(work)
        walls.append(pipe_wall / loop_wall)
        cpus.append(pipe_cpu / loop_cpu)
        loop_walls.append(loop_wall)
        loop_cpus.append(loop_cpu)
        print(
            f"N = 200, repeat {r + 1}: loop {loop_wall:.1f} s wall, {loop_cpu:.1f} s CPU; "
            f"pipeline {pipe_wall:.1f} s wall, {pipe_cpu:.1f} s CPU, {peak_200:.0f} MB peak",
            flush=True,
        )
    print("\nthe jobs of the first clean run at N = 200 (from their logs):")
    for name, (wall, cpu) in jobs.items():
        print(f"  {name:<28} {wall:6.2f} s wall {cpu:6.2f} s CPU")
    rows.append(("clean snakemake -c2, N = 200, wall / plain loop", median_range(walls), "<= 1.0"))
    rows.append(("same, CPU time / plain loop's CPU time", median_range(cpus), "<= 1.3"))

    shares = logging_share(config, 200, args.repeats)
    print(f"\nlogging share of the rollout stage's CPU, per repeat: {shares}", flush=True)
    rows.append(
        ("replay logging, share of the rollout stage's CPU", median_range(shares, ".1%"), "<= 10%")
    )

    if not args.quick:
        loop_per_state = statistics.median(loop_walls) / 200
        peaks = {}
        for n in (2_000, args.scale_n):
            wall, cpu, peaks[n], work = run_pipeline(n)
            shutil.rmtree(work)
            loop = loop_per_state * n
            print(
                f"N = {n:,}: pipeline {wall:.0f} s wall, {cpu:.0f} s CPU, {peaks[n]:.0f} MB peak;"
                f" the loop, scaled: {loop:.0f} s",
                flush=True,
            )
            rows.append(
                (
                    f"clean run, N = {n:,}, wall / plain loop (scaled)",
                    f"{wall / loop:.2f}",
                    "<= 0.55" if n == args.scale_n else "",
                )
            )
        rows.append(
            (
                f"peak memory of any process, N = {args.scale_n:,}",
                f"{peaks[args.scale_n]:.0f} MB",
                "<= 400 MB",
            )
        )
        rows.append(
            (
                "same at N = 2,000, relative",
                f"{peaks[2_000] / peaks[args.scale_n] - 1:+.1%}",
                "within 10%",
            )
        )

    if args.slurm:
        t0 = time.perf_counter()
        proc = subprocess.run(["bash", str(REPO_ROOT / "tests/cluster/run_slurm_test.sh")])
        verdict = "passes" if proc.returncode == 0 else f"FAILS (exit {proc.returncode})"
        rows.append(
            (
                "SLURM round trip, one-node cluster",
                f"{verdict}, {time.perf_counter() - t0:.0f} s",
                "passes",
            )
        )

    print(
        f"\n{n_conditions} conditions; the plain loop: {statistics.median(loop_walls):.1f} s "
        f"wall, {statistics.median(loop_cpus):.1f} s CPU on 200 states (median)\n"
    )
    width = max(len(r[0]) for r in rows)
    print(f"{'figure':<{width}}  {'measured (median, range)':<28}  bar")
    for label, value, bar in rows:
        print(f"{label:<{width}}  {value:<28}  {bar}")


if __name__ == "__main__":
    main()
