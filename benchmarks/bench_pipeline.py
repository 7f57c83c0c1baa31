"""Benchmark: the pipeline's engine against the reference stepper and bare mujoco.rollout;
the cost of replay logging; a clean `snakemake -c2` against a plain single-process loop; and
a replay of every failed episode.

Figures are ratios measured in this one run (the machines are shared and noisy):

    python benchmarks/bench_pipeline.py            # the built-in experiment: 200 states x 2
    python benchmarks/bench_pipeline.py --n 50     # quicker
"""

from __future__ import annotations

import argparse
import os
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
from gantry_lift.protocol import control_sequence
from gantry_lift.simulate import episode_model, initial_physics_state, reference_episode
from gantry_lift.states import STATE_PARAMETERS, states_from_table
from mujoco import rollout

from mjtrial import REPO_ROOT, provenance
from mjtrial.design.states import generate_initial_states
from mjtrial.files.layout import CONFIG_FILE, RESULTS_DIR, Layout
from mjtrial.replay import replay_episode
from mjtrial.sim.physics import load_model
from mjtrial.stages.rollout import run_shard
from mjtrial.stages.stamping import config_slice
from mjtrial.stages.states import build_states


def timed(fn):
    start = time.perf_counter()
    result = fn()
    return time.perf_counter() - start, result


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--n", type=int, help="states (default: the config's n)")
    parser.add_argument("--threads", type=int, default=2)
    parser.add_argument("--repeats", type=int, default=9, help="repeats of the stage timings")
    parser.add_argument(
        "--rate-hz", type=float, help="replay logging rate (default: the config's rate_hz)"
    )
    args = parser.parse_args()
    os.environ.setdefault("CI", "1")  # rerun's CLI: no analytics files in the home folder
    config = yaml.safe_load((REPO_ROOT / CONFIG_FILE).read_text())
    if args.rate_hz:
        config["recording"]["rate_hz"] = args.rate_hz
    print(f"replay logging at {config['recording']['rate_hz']:g} Hz")
    n = args.n or config["states"]["n"]
    s = config["states"]
    states = states_from_table(
        generate_initial_states(
            seed=s["seed"], n=n, ranges=s["ranges"], parameters=STATE_PARAMETERS
        )
    )
    model_file = REPO_ROOT / config["model"]
    model = load_model(model_file)
    conditions = {name: c["lift_time"] for name, c in config["conditions"].items()}
    episodes = n * len(conditions)
    print(f"{episodes} episodes: {n} states x {len(conditions)} conditions, {args.threads} threads")

    # 1. Plain single-process loop: the literal reference stepper, one episode after another.
    t_loop, reference = timed(
        lambda: {
            name: [reference_episode(model, st, lift_time=lt)[0][-1] for st in states]
            for name, lt in conditions.items()
        }
    )

    # 2. Bare mujoco.rollout on the same episodes, inputs prepared beforehand (the ceiling).
    prepared = {}
    for name, lt in conditions.items():
        models = [episode_model(model, st.mass) for st in states]
        initial = np.stack(
            [initial_physics_state(m, st) for m, st in zip(models, states, strict=True)]
        )
        prepared[name] = (models, initial, control_sequence(lt, timestep=model.opt.timestep)[0])
    datas = [mujoco.MjData(model) for _ in range(args.threads)]

    def bare():
        finals = {}
        with rollout.Rollout(nthread=args.threads) as runner:
            for name, (models, initial, ctrl) in prepared.items():
                physics, _ = runner.rollout(models, datas, initial, ctrl[None])
                finals[name] = physics[:, -1]
        return finals

    # 3. The rollout stage as the pipeline runs it (read states, copy models, roll out in
    # batches, classify failures, write the stamped tables), without and with replay logging.
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        states_path = tmp / "states.parquet"
        build_states(states_slice={**s, "n": n}, output=states_path, repo_root=REPO_ROOT)

        def stage(record: bool):
            outputs = {}
            for name in conditions:
                folder = tmp / name  # a folder of recordings
                shutil.rmtree(folder, ignore_errors=True)
                outputs[name] = run_shard(
                    condition_slice=config_slice("rollout", config, condition=name),
                    states_path=states_path,
                    model_file=model_file,
                    first=0,
                    stop=n,
                    output_table=tmp / f"{name}.parquet",
                    output_recording=folder if record else None,
                    nthread=args.threads,
                    rule=f"rollout:{name}",
                )
            return outputs

        runs = {"bare": bare, "stage": lambda: stage(False), "stage+rrd": lambda: stage(True)}
        times: dict[str, list[float]] = {k: [] for k in runs}
        cpu: dict[str, list[float]] = {k: [] for k in runs}  # CPU seconds of this process
        outputs = {}
        for i in range(args.repeats):
            # back to back, in an order that flips every repeat (ABBA), so that a drift in the
            # machine's load, or what one run leaves behind (the disk's writeback of the .rrd
            # files), weighs on each kind of run alike
            for kind in runs if i % 2 == 0 else reversed(runs):
                cpu0 = time.process_time()
                t, outputs[kind] = timed(runs[kind])
                times[kind].append(t)
                cpu[kind].append(time.process_time() - cpu0)
        bare_finals, stage_out = outputs["bare"], outputs["stage"]
        t_bare, t_stage, t_rec = (statistics.median(times[k]) for k in times)
        # paired within a repeat: the three ran back to back, under the same machine load
        logging_cost = [r / s - 1 for r, s in zip(times["stage+rrd"], times["stage"], strict=True)]
        logging_cpu = [r / s - 1 for r, s in zip(cpu["stage+rrd"], cpu["stage"], strict=True)]
        cpu_per_recording = [
            (r - s) / episodes for r, s in zip(cpu["stage+rrd"], cpu["stage"], strict=True)
        ]
        stage_share = [b / s for b, s in zip(times["bare"], times["stage"], strict=True)]

    for name in conditions:
        np.testing.assert_array_equal(np.stack(reference[name]), bare_finals[name])
        heights = np.stack(reference[name])[:, 1 + 7]
        assert np.array_equal(heights, stage_out[name].column("final_height").to_numpy()), name
    print("engine, bare rollout and reference agree on every episode's final state: yes")

    # 4. A clean `snakemake -c2` of the experiment, in a fresh copy of the workflow; then a
    # replay of every failed episode from its results.
    with tempfile.TemporaryDirectory() as tmp:
        work = Path(tmp)
        for name in ("Snakefile", "workflow", "config", "models", "tasks", "profiles"):
            src = REPO_ROOT / name
            (shutil.copytree if src.is_dir() else shutil.copy)(src, work / name)
        if args.n or args.rate_hz:
            cfg = yaml.safe_load((work / CONFIG_FILE).read_text())
            cfg["states"]["n"] = n
            cfg["recording"]["rate_hz"] = config["recording"]["rate_hz"]
            (work / CONFIG_FILE).write_text(yaml.safe_dump(cfg, sort_keys=False))
        snakemake = str(Path(sys.executable).parent / "snakemake")
        t_smk, proc = timed(
            lambda: subprocess.run(
                [snakemake, f"-c{args.threads}", "--quiet", "all"],
                cwd=work,
                capture_output=True,
                text=True,
            )
        )
        if proc.returncode:
            sys.exit(f"snakemake failed:\n{proc.stderr[-2000:]}")
        layout = Layout.of(config["experiment"], base=work / RESULTS_DIR)
        results = layout.root
        rrd_sizes: dict[str, int] = {}  # a folder of recordings counts as one
        for p in results.rglob("*.rrd"):
            rel = p.relative_to(results)
            folder = provenance.is_recording_folder(p.parent)
            key = f"{rel.parent.as_posix()}/" if folder else rel.as_posix()
            rrd_sizes[key] = rrd_sizes.get(key, 0) + p.stat().st_size
        failed = [
            (name, row["state_id"])
            for name in conditions
            for row in pq.read_table(layout.rollout_table(name)).to_pylist()
            if not row["success"]
        ]

        def replay_all():
            for name, state_id in failed:
                replay_episode(
                    condition=name,
                    state_id=state_id,
                    output=work / "replay.rrd",
                    repo_root=work,
                )

        t_replay, _ = timed(replay_all)  # raises ReplayMismatch on the first that differs
    print(f"replayed all {len(failed)} failed episodes: every outcome and final state as recorded")

    rows = [
        ("reference stepper (copies the state every step: the oracle, 1 process)", t_loop),
        (f"bare mujoco.rollout, {args.threads} threads (median)", t_bare),
        ("rollout stage without replay logging (median)", t_stage),
        ("rollout stage with replay logging (median)", t_rec),
        (f"clean snakemake -c{args.threads}, whole pipeline", t_smk),
    ]
    print(f"\n{'':<58} {'wall s':>8} {'episodes/s':>11}")
    for label, t in rows:
        print(f"{label:<58} {t:8.2f} {episodes / t:11.1f}")
    print(
        f"{'replay of each failed episode (1 thread, full-rate .rrd)':<58} "
        f"{t_replay / max(1, len(failed)):8.3f} s each"
    )
    print()
    for name, size in sorted(rrd_sizes.items()):
        print(f"{name:<40} {size / 1e6:8.1f} MB")
    print(f"{'all .rrd files':<40} {sum(rrd_sizes.values()) / 1e6:8.1f} MB  (goal < 50 MB)")
    print()
    print(f"engine speed-up over the reference stepper:       {t_loop / t_rec:6.1f}x")
    print(
        f"rollout stage throughput / bare mujoco.rollout:   {statistics.median(stage_share):6.3f}"
        f"  (goal >= 0.90; median of {args.repeats} paired repeats,"
        f" range {min(stage_share):.3f} to {max(stage_share):.3f})"
    )
    print(
        f"replay logging cost / rollout stage:              {statistics.median(logging_cost):+6.1%}"
        f"  (goal <= +10%; median of {args.repeats} paired repeats,"
        f" range {min(logging_cost):+.1%} to {max(logging_cost):+.1%})"
    )
    print(
        f"  the same in CPU time (all threads):             {statistics.median(logging_cpu):+6.1%}"
        f"  (range {min(logging_cpu):+.1%} to {max(logging_cpu):+.1%}),"
        f" {1e3 * statistics.median(cpu_per_recording):.2f} ms of CPU per recording"
    )
    print(
        f"clean snakemake wall time / reference stepper:    {t_smk / t_loop:6.3f}  "
        "(not a speed baseline: see bench_vs_plain_loop.py)"
    )


if __name__ == "__main__":
    main()
