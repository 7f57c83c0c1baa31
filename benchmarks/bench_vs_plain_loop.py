"""Benchmark: a clean `snakemake -c2` against the plain loop a researcher writes without it.

The baseline is the course's worked example: one `MjData` per episode, `mj_step` in a Python
loop, the controls set between holds, nothing recorded per step, every state under every
condition, one process. The pipeline does far more (recordings of every episode, the failure
taxonomy, the analysis with its bootstrap, figures, the report, stamps), so this is the price
of all that, measured against what a competent user would write instead.

    python benchmarks/bench_vs_plain_loop.py               # N = 200, 3 alternating repeats
    python benchmarks/bench_vs_plain_loop.py --n 2000 --repeats 1

Each repeat runs the loop and a clean pipeline (a fresh copy of the workflow) back to back, in
an order that flips every repeat; the figures are medians of the paired ratios, with their
range. CPU is all processes' user + system time; peak memory is the largest single process of
the pipeline run (the largest job, or Snakemake itself), from the kernel's accounting of
waited-for children.
"""

from __future__ import annotations

import argparse
import copy
import resource
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import mujoco
import numpy as np
import yaml

from mjtrial import REPO_ROOT
from mjtrial.layout import CONFIG_FILE
from mjtrial.protocol import CTRL_GRIPPER, CTRL_Z, PROTOCOL, hold_steps
from mjtrial.simulate import load_model
from mjtrial.states import generate_initial_states, states_from_table

WORKFLOW = ("Snakefile", "workflow", "config", "models", "profiles")


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


def cpu_of_children() -> float:
    usage = resource.getrusage(resource.RUSAGE_CHILDREN)
    return usage.ru_utime + usage.ru_stime


def run_plain_loop(config: dict, n: int) -> tuple[float, float, dict[str, np.ndarray]]:
    """(wall s, CPU s, final heights per condition) of the loop over n states."""
    model = load_model(REPO_ROOT / config["model"])
    s = config["states"]
    states = states_from_table(generate_initial_states(seed=s["seed"], n=n, ranges=s["ranges"]))
    t0, c0 = time.perf_counter(), time.process_time()
    heights = {
        name: np.array([plain_loop_episode(model, st, c["lift_time"]) for st in states])
        for name, c in config["conditions"].items()
    }
    return time.perf_counter() - t0, time.process_time() - c0, heights


def run_pipeline(n: int) -> tuple[float, float, Path]:
    """(wall s, CPU s of every process) of a clean `snakemake -c2` on n states, and its folder."""
    work = Path(tempfile.mkdtemp(prefix="mjtrial-bench-"))
    for name in WORKFLOW:
        src = REPO_ROOT / name
        (shutil.copytree if src.is_dir() else shutil.copy)(src, work / name)
    if n != 200:
        path = work / CONFIG_FILE
        cfg = yaml.safe_load(path.read_text())
        cfg["states"]["n"] = n
        path.write_text(yaml.safe_dump(cfg, sort_keys=False))
    snakemake = str(Path(sys.executable).parent / "snakemake")
    c0, t0 = cpu_of_children(), time.perf_counter()
    proc = subprocess.run([snakemake, "-c2", "--quiet"], cwd=work, capture_output=True, text=True)
    wall, cpu = time.perf_counter() - t0, cpu_of_children() - c0
    if proc.returncode:
        sys.exit(f"snakemake failed:\n{proc.stderr[-2000:]}")
    return wall, cpu, work


def median_range(values: list[float]) -> str:
    return f"{statistics.median(values):.2f} ({min(values):.2f}-{max(values):.2f})"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--n", type=int, default=200, help="states (each under every condition)")
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument(
        "--loop-n",
        type=int,
        default=200,
        help="states the loop runs; its time is scaled linearly to --n (the loop is linear)",
    )
    args = parser.parse_args()
    config = yaml.safe_load((REPO_ROOT / CONFIG_FILE).read_text())
    scale = args.n / args.loop_n
    walls, cpus = [], []
    for r in range(args.repeats):
        order = ("loop", "pipeline") if r % 2 == 0 else ("pipeline", "loop")
        for what in order:
            if what == "loop":
                loop_wall, loop_cpu, heights = run_plain_loop(config, args.loop_n)
            else:
                pipe_wall, pipe_cpu, work = run_pipeline(args.n)
        if args.n == args.loop_n:  # the pipeline's outcomes are the loop's, bit for bit
            import pyarrow.parquet as pq

            for name, h in heights.items():
                table = pq.read_table(
                    work / "results" / config["experiment"] / "rollouts" / f"{name}.parquet"
                )
                assert np.array_equal(table.column("final_height").to_numpy(), h), name
        shutil.rmtree(work)
        walls.append(pipe_wall / (loop_wall * scale))
        cpus.append(pipe_cpu / (loop_cpu * scale))
        print(
            f"repeat {r + 1}: loop {loop_wall:.1f} s wall, {loop_cpu:.1f} s CPU on "
            f"{args.loop_n} states; pipeline {pipe_wall:.1f} s wall, {pipe_cpu:.1f} s CPU on "
            f"{args.n} states"
        )
    peak_mb = resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss / 1024
    episodes = args.n * len(config["conditions"])
    print(f"\n{episodes} episodes ({args.n} states x {len(config['conditions'])} conditions)")
    print(f"clean snakemake -c2, wall / plain loop (median, range):  {median_range(walls)}")
    print(f"clean snakemake -c2, CPU  / plain loop (median, range):  {median_range(cpus)}")
    print(f"peak resident memory of any process of the runs:       {peak_mb:.0f} MB")


if __name__ == "__main__":
    main()
