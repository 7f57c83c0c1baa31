"""Benchmark: one rollout job's work against the bare physics of the same episodes.

For each built-in experiment's conditions, `run_shard` (task and states, stamp, episode setup,
physics, measures and outcome, every episode recorded at the config's rate, table, row hash,
write) against the same episodes' physics alone, inputs prepared beforehand:

- open loop (the gantry, config/config.yaml): one `mujoco.rollout` call on the same models,
  initial states and controls;
- closed loop (the cart-pole, config/cartpole_latency.yaml, and the same condition with a
  policy file, policies/cartpole_mlp/seed-1.onnx): the plain per-episode `mj_step` loop that
  calls the same policy once per control step (`closed_loop.reference_episode`), the honest
  baseline of a feedback controller.

One thread each, as a rollout job runs (`threads: 1`). Job and baseline alternate which runs
first every repeat (the machine is shared and noisy); the figures are the medians of the paired
ratios job / baseline, wall and CPU, and the job's phases (its log's `# phases:` line,
`mjtrial.phases`) of the last repeat.

    python benchmarks/bench_rollout_overhead.py                 # every case, 3 repeats
    python benchmarks/bench_rollout_overhead.py --cases gantry --repeats 5
"""

from __future__ import annotations

import argparse
import logging
import os
import shutil
import statistics
import tempfile
import time
from collections.abc import Callable
from pathlib import Path

import mujoco
import numpy as np
import yaml
from mujoco import rollout

from mjtrial import REPO_ROOT, closed_loop
from mjtrial.conditions import POLICY
from mjtrial.phases import PHASES_PREFIX
from mjtrial.stages.rollout import (
    condition_parameters,
    condition_task,
    read_state_values,
    run_shard,
)
from mjtrial.stages.stamping import config_slice
from mjtrial.stages.states import build_states
from mjtrial.task import ClosedLoop, OpenLoop, call

CASES = {
    # name: (config file, its conditions run, a policy file replacing the task's policy)
    "gantry": ("config/config.yaml", None, None),
    "cartpole": ("config/cartpole_latency.yaml", None, None),
    "policy_file": (
        "config/cartpole_latency.yaml",
        ["latency_20ms"],
        "policies/cartpole_mlp/seed-1.onnx",
    ),
}


class PhaseLines(logging.Handler):
    """Keeps the rollout stage's `# phases:` lines."""

    def __init__(self) -> None:
        super().__init__()
        self.lines: list[str] = []

    def emit(self, record: logging.LogRecord) -> None:
        message = record.getMessage()
        if message.startswith(PHASES_PREFIX):
            self.lines.append(message)


def baseline_of(slice_: dict, states: Path, model_file: Path, n: int) -> Callable[[], object]:
    """The bare physics of the condition's episodes, its inputs prepared now."""
    bound = condition_task(slice_, model_file)
    task, model = bound.task, bound.model
    values = read_state_values(states, task, first=0, stop=n)
    params = task.parameters(condition_parameters(bound, slice_))
    scratch = mujoco.MjData(model)
    names = [p.name for p in task.state_parameters]
    models, initial = [], []
    for i in range(n):
        m, s = bound.episode({k: float(values[k][i]) for k in names}, scratch=scratch)
        models.append(m)
        initial.append(s)
    initial = np.stack(initial)
    controller = task.controller
    if isinstance(controller, OpenLoop):
        ctrl = np.asarray(call(task, "controls", controller.controls, model, params), float)
        datas = [mujoco.MjData(model)]

        def bare() -> object:
            with rollout.Rollout(nthread=1) as runner:
                return runner.rollout(models, datas, initial, ctrl[None])[0][:, -1]

        return bare
    assert isinstance(controller, ClosedLoop)
    timing = call(task, "timing", controller.timing, model, params)
    policy = call(task, "policy", controller.policy, model, params)
    rows = {k: values[k] for k in names}
    pushes = call(task, "pushes", controller.pushes, model, rows) if controller.pushes else None
    observers = [
        bound.observer(
            controller.observations,
            {k: rows[k][i : i + 1] for k in names},
            params=params,
            n_controls=timing.n_controls,
            models=models[i : i + 1],
        )
        for i in range(n)
    ]

    def loop() -> object:
        return [
            closed_loop.reference_episode(
                models[i],
                initial[i],
                policy,
                observers[i],
                timing,
                pushes=pushes.rows(slice(i, i + 1)) if pushes else None,
                actuation=bound.actuation,
            ).physics[0, -1]
            for i in range(n)
        ]

    return loop


def run_case(name: str, n: int, repeats: int, tmp: Path, record: str) -> None:
    config_file, conditions, policy = CASES[name]
    config = yaml.safe_load((REPO_ROOT / config_file).read_text())
    config["recording"]["episodes"] = record
    states = tmp / f"{name}-states.parquet"
    build_states(
        states_slice={**config_slice("states", config), "n": n},
        output=states,
        repo_root=REPO_ROOT,
    )
    model_file = REPO_ROOT / config["model"]
    slices = []
    for c in conditions or list(config["conditions"]):
        slice_ = dict(config_slice("rollout", config, condition=c))
        if policy:
            slice_[POLICY] = policy
        slices.append(slice_)
    bares = [baseline_of(s, states, model_file, n) for s in slices]

    def job() -> None:
        for s in slices:
            folder = tmp / f"{name}-{s['condition']}"
            shutil.rmtree(folder, ignore_errors=True)
            run_shard(
                condition_slice=s,
                states_path=states,
                model_file=model_file,
                first=0,
                stop=n,
                output_table=tmp / f"{name}-{s['condition']}.parquet",
                output_recording=None if record == "none" else folder,
                nthread=1,
                rule=f"rollout:{s['condition']}",
            )

    def bare() -> None:
        for b in bares:
            b()

    lines = PhaseLines()
    logging.getLogger("mjtrial").addHandler(lines)
    logging.getLogger("mjtrial").setLevel(logging.INFO)
    spent: dict[str, list[tuple[float, float]]] = {"job": [], "bare": []}
    for r in range(repeats):
        for what in ("job", "bare") if r % 2 == 0 else ("bare", "job"):
            if what == "job":
                lines.lines.clear()
            w0, c0 = time.perf_counter(), time.process_time()
            (job if what == "job" else bare)()
            spent[what].append((time.perf_counter() - w0, time.process_time() - c0))
    logging.getLogger("mjtrial").removeHandler(lines)
    pairs = list(zip(spent["job"], spent["bare"], strict=True))
    wall = [j[0] / b[0] for j, b in pairs]
    cpu = [j[1] / b[1] for j, b in pairs]
    med = statistics.median
    print(
        f"\n{name}: {len(slices)} condition(s) x {n} states, recording {record}, "
        f"{repeats} paired repeats"
    )
    print(
        f"  baseline {med(b[0] for _, b in pairs):.3f} s wall {med(b[1] for _, b in pairs):.3f} "
        f"s CPU; job {med(j[0] for j, _ in pairs):.3f} s wall {med(j[1] for j, _ in pairs):.3f} "
        "s CPU (medians)"
    )
    print(
        f"  job / baseline: wall {med(wall):.3f}x ({min(wall):.3f}-{max(wall):.3f}), "
        f"CPU {med(cpu):.3f}x ({min(cpu):.3f}-{max(cpu):.3f})"
    )
    for line in lines.lines:  # the last job's, one per condition
        print("  " + line.replace("), ", ")\n      "))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--cases", nargs="+", choices=list(CASES), default=list(CASES))
    parser.add_argument("--n", type=int, default=200, help="states per condition")
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--record", choices=("all", "failed", "none"), default="all")
    args = parser.parse_args()
    os.environ.setdefault("RERUN_ANALYTICS", "0")
    with tempfile.TemporaryDirectory(prefix="mjtrial-overhead-") as tmp:
        for name in args.cases:
            run_case(name, args.n, args.repeats, Path(tmp), args.record)


if __name__ == "__main__":
    main()
