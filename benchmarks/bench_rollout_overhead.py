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
`mjtrial.sim.phases`) of the last repeat.

With `--processes`, each side also runs as a job does, in a process of its own: the job is
workflow/scripts/rollout.py's work (`pyarrow_without_pandas`, then `run_shard`) in a fresh
interpreter, its CPU and wall from start to exit (imports and the task's module included; not
Snakemake's script preamble); the baseline is a fresh interpreter's `import mujoco` plus the
bare physics above.

    python benchmarks/bench_rollout_overhead.py                 # every case, 3 repeats
    python benchmarks/bench_rollout_overhead.py --cases gantry --repeats 5 --processes
    python benchmarks/bench_rollout_overhead.py --cases gantry --against ../earlier/src
"""

from __future__ import annotations

import argparse
import json
import logging
import os
import resource
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable
from pathlib import Path

import mujoco
import numpy as np
import yaml
from mujoco import rollout

from mjtrial import REPO_ROOT
from mjtrial.design.conditions import POLICY
from mjtrial.sim import closed_loop
from mjtrial.sim.phases import PHASES_PREFIX
from mjtrial.stages.condition import condition_parameters, condition_task
from mjtrial.stages.rollout import read_state_values, run_shard
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


def child_seconds(args: list[str], src: str | None = None) -> tuple[float, float]:
    """Wall and CPU (user + system) seconds of a fresh interpreter running `args` with the
    package source `src` (default: this tree's)."""
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    w0 = time.perf_counter()
    env = os.environ | {"PYTHONPATH": src or SRC}
    subprocess.run([sys.executable, *args], check=True, env=env)
    wall = time.perf_counter() - w0
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    return wall, (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)


SRC = str(REPO_ROOT / "src")
JOB = """
import sys, json
from pathlib import Path
try:  # an earlier commit's tree (PYTHONPATH) may not have it
    from mjtrial.nopandas import pyarrow_without_pandas
    pyarrow_without_pandas()
except ImportError:
    pass
from mjtrial.stages.rollout import run_shard
kwargs = json.loads(sys.argv[1])
run_shard(**{k: Path(v) if k in PATHS else v for k, v in kwargs.items()})
"""
PATHS = ("states_path", "model_file", "output_table", "output_recording")
BARE_IMPORTS = "import numpy, mujoco\nfrom mujoco import rollout"


def run_case(
    name: str,
    n: int,
    repeats: int,
    tmp: Path,
    record: str,
    processes: bool,
    against: str | None = None,
) -> None:
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

    def job_processes(src: str | None = None) -> tuple[float, float]:
        wall = cpu = 0.0
        for s in slices:
            folder = tmp / f"{name}-{s['condition']}"
            shutil.rmtree(folder, ignore_errors=True)
            kwargs = {
                "condition_slice": s,
                "states_path": str(states),
                "model_file": str(model_file),
                "first": 0,
                "stop": n,
                "output_table": str(tmp / f"{name}-{s['condition']}.parquet"),
                "output_recording": None if record == "none" else str(folder),
                "nthread": 1,
                "rule": f"rollout:{s['condition']}",
            }
            code = JOB.replace("PATHS", repr(PATHS))
            w, c = child_seconds(["-c", code, json.dumps(kwargs)], src)
            wall, cpu = wall + w, cpu + c
        return wall, cpu

    def bare_processes() -> tuple[float, float]:
        wall = cpu = 0.0
        for b in bares:
            w, c = child_seconds(["-c", BARE_IMPORTS])
            w0, c0 = time.perf_counter(), time.process_time()
            b()
            wall += w + time.perf_counter() - w0
            cpu += c + time.process_time() - c0
        return wall, cpu

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
    print(
        f"\n{name}: {len(slices)} condition(s) x {n} states, recording {record}, "
        f"{repeats} paired repeats"
    )
    print_pairs("in this process", spent)
    for line in lines.lines:  # the last job's, one per condition
        print("  " + line.replace("), ", ")\n      "))
    if processes:
        spent = {"job": [], "bare": []}
        for r in range(repeats):
            for what in ("job", "bare") if r % 2 == 0 else ("bare", "job"):
                spent[what].append(job_processes() if what == "job" else bare_processes())
        print_pairs("a process each", spent)
    if against:
        spent = {"job": [], "bare": []}  # bare: the other tree's job
        for r in range(repeats):
            for src in (SRC, against) if r % 2 == 0 else (against, SRC):
                spent["job" if src == SRC else "bare"].append(job_processes(src))
        print_pairs(f"a process each, this tree's job against {against}'s", spent)


def print_pairs(what: str, spent: dict[str, list[tuple[float, float]]]) -> None:
    pairs = list(zip(spent["job"], spent["bare"], strict=True))
    wall = [j[0] / b[0] for j, b in pairs]
    cpu = [j[1] / b[1] for j, b in pairs]
    med = statistics.median
    print(f"  {what}:")
    print(
        f"  baseline {med(b[0] for _, b in pairs):.3f} s wall {med(b[1] for _, b in pairs):.3f} "
        f"s CPU; job {med(j[0] for j, _ in pairs):.3f} s wall {med(j[1] for j, _ in pairs):.3f} "
        "s CPU (medians)"
    )
    print(
        f"  job / baseline: wall {med(wall):.3f}x ({min(wall):.3f}-{max(wall):.3f}), "
        f"CPU {med(cpu):.3f}x ({min(cpu):.3f}-{max(cpu):.3f})"
    )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--cases", nargs="+", choices=list(CASES), default=list(CASES))
    parser.add_argument("--n", type=int, default=200, help="states per condition")
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--record", choices=("all", "failed", "none"), default="all")
    parser.add_argument(
        "--processes", action="store_true", help="also each side in a process of its own"
    )
    parser.add_argument(
        "--against",
        metavar="SRC",
        help="also this tree's job processes against another tree's (its src folder, e.g. an "
        "earlier commit's worktree), alternating",
    )
    args = parser.parse_args()
    os.environ.setdefault("RERUN_ANALYTICS", "0")
    with tempfile.TemporaryDirectory(prefix="mjtrial-overhead-") as tmp:
        for name in args.cases:
            run_case(
                name,
                args.n,
                args.repeats,
                Path(tmp),
                args.record,
                args.processes,
                args.against,
            )


if __name__ == "__main__":
    main()
