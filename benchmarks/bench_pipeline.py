"""Benchmark: the pipeline's engine against the reference stepper and bare mujoco.rollout,
and a clean `snakemake -c2` against a plain single-process loop over the same episodes.

Figures are ratios measured in this one run (the machines are shared and noisy):

    python benchmarks/bench_pipeline.py            # the built-in experiment: 200 states x 2
    python benchmarks/bench_pipeline.py --n 50     # quicker
"""

from __future__ import annotations

import argparse
import os
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import mujoco
import numpy as np
import yaml
from mujoco import rollout

from mjtrial import REPO_ROOT, pipeline
from mjtrial.protocol import control_sequence
from mjtrial.simulate import (
    episode_model,
    initial_physics_state,
    load_model,
    reference_episode,
)
from mjtrial.states import generate_initial_states, states_from_table


def timed(fn):
    start = time.perf_counter()
    result = fn()
    return time.perf_counter() - start, result


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--n", type=int, help="states (default: the config's n)")
    parser.add_argument("--threads", type=int, default=2)
    args = parser.parse_args()
    config = yaml.safe_load((REPO_ROOT / "config" / "config.yaml").read_text())
    n = args.n or config["states"]["n"]
    s = config["states"]
    table = generate_initial_states(seed=s["seed"], n=n, ranges=s["ranges"])
    states = states_from_table(table)
    model = load_model(REPO_ROOT / config["model"])
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

    t_bare, bare_finals = timed(bare)

    # 3. The rollout stage as the pipeline runs it: read states, copy models, roll out in
    # batches, compute outcomes, write the stamped tables.
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        states_path = tmp / "states.parquet"
        pipeline.build_states(states_slice={**s, "n": n}, output=states_path, repo_root=REPO_ROOT)

        def stage():
            return {
                name: pipeline.run_condition(
                    condition_slice=pipeline.config_slice("rollout", config, condition=name),
                    states_path=states_path,
                    model_file=REPO_ROOT / config["model"],
                    output_table=tmp / f"{name}.parquet",
                    output_nominal=tmp / f"{name}.nominal.json",
                    nthread=args.threads,
                )
                for name, lt in conditions.items()
            }

        t_stage, stage_out = timed(stage)

    for name in conditions:
        np.testing.assert_array_equal(np.stack(reference[name]), bare_finals[name])
        heights = np.stack(reference[name])[:, 1 + 7]
        assert np.array_equal(heights, stage_out[name]["final_height"]), name
    print("engine, bare rollout and reference agree on every episode's final state: yes")

    # 4. A clean `snakemake -c2` of the experiment, in a fresh copy of the workflow.
    with tempfile.TemporaryDirectory() as tmp:
        work = Path(tmp)
        for name in ("Snakefile", "workflow", "config", "models", "profiles"):
            src = REPO_ROOT / name
            (shutil.copytree if src.is_dir() else shutil.copy)(src, work / name)
        if args.n:
            cfg = yaml.safe_load((work / "config" / "config.yaml").read_text())
            cfg["states"]["n"] = n
            (work / "config" / "config.yaml").write_text(yaml.safe_dump(cfg, sort_keys=False))
        snakemake = str(Path(sys.executable).parent / "snakemake")
        t_smk, proc = timed(
            lambda: subprocess.run(
                [snakemake, f"-c{args.threads}", "--quiet", "all"],
                cwd=work,
                capture_output=True,
                text=True,
                env=os.environ,
            )
        )
        if proc.returncode:
            sys.exit(f"snakemake failed:\n{proc.stderr[-2000:]}")

    rows = [
        ("reference stepper (plain mj_step loop, 1 process)", t_loop),
        (f"bare mujoco.rollout, {args.threads} threads", t_bare),
        (f"rollout stage (pipeline.run_condition), {args.threads} threads", t_stage),
        (f"clean snakemake -c{args.threads}, whole pipeline", t_smk),
    ]
    print(f"\n{'':<62} {'wall s':>8} {'episodes/s':>11}")
    for label, t in rows:
        print(f"{label:<62} {t:8.2f} {episodes / t:11.1f}")
    print()
    print(f"engine speed-up over the reference stepper:      {t_loop / t_stage:6.1f}x")
    print(
        f"rollout stage throughput / bare mujoco.rollout:  {t_bare / t_stage:6.3f}  (goal >= 0.90)"
    )
    print(f"clean snakemake wall time / plain loop:          {t_smk / t_loop:6.3f}  (goal <= 1.00)")


if __name__ == "__main__":
    main()
