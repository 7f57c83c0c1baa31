"""Benchmark: a low-level controller at the physics rate (robosuite's Lift, `tasks/robosuite_lift/`)
against what a user would run instead.

The same episodes (the task's states: cube offset and yaw, the arm's Gaussian start noise; the
scripted policy, `close_steps` 3) three ways:

- the engine: `engine.iter_batches`, as a rollout job runs it (the policy once per action on
  the batch, `mj_step1` / the batched `OperationalSpace` / `mj_step2` per physics step,
  the task's measures and outcome), nothing recorded, on 1 and 2 threads;
- the plain loop a user writes, one episode at a time, nothing recorded: `mj_step1`, the
  controller, `mj_step2` at every physics step, the policy at every 25th. Its controller is
  robosuite's arithmetic written for one episode (`tasks/robosuite_lift/osc_reference.py`, as
  robosuite writes it), or the engine's own controller on a batch of one
  (`low_level.PlainEpisode`); the faster of the two is the baseline;
- with `--robosuite`, robosuite 1.5.2's own env stepping the same states with the same policy
  (`robosuite_env_time.py`, in robosuite's own environment on MuJoCo 3.9.0: robosuite does not
  build Lift on 3.14), CPU seconds per episode.

    python benchmarks/bench_low_level.py                      # 20 episodes, 3 repeats
    python benchmarks/bench_low_level.py --episodes 40 --robosuite
    python benchmarks/bench_low_level.py --episodes 64 --batch 16 64   # other batch sizes

It prints each way's CPU seconds per episode and wall seconds, and the engine's speed over the
plain loop (wall, the medians of paired ratios over repeats that alternate their order) and
over robosuite's env (CPU per episode).
"""

from __future__ import annotations

import argparse
import json
import statistics
import subprocess
import sys
import tempfile
import time
from functools import partial
from pathlib import Path

import mujoco
import numpy as np

from mjtrial import REPO_ROOT
from mjtrial.sim.engine import LOW_LEVEL_BATCH, iter_batches
from mjtrial.sim.low_level import PlainEpisode
from mjtrial.sim.physics import load_model
from mjtrial.task import BoundTask, load_task

sys.path.insert(0, str(REPO_ROOT / "tasks"))
from robosuite_lift import osc_reference, scripted  # noqa: E402
from robosuite_lift.task import CUBE_BODY, N_SUBSTEPS, operational_space  # noqa: E402

TASK = REPO_ROOT / "tasks" / "robosuite_lift" / "task.py"
CLOSE_STEPS = 3


def draw_states(n: int, seed: int = 0) -> dict[str, np.ndarray]:
    """The task's state parameters as robosuite draws them."""
    rng = np.random.default_rng(seed)
    out = {
        "cube_dx": rng.uniform(-0.03, 0.03, n),
        "cube_dy": rng.uniform(-0.03, 0.03, n),
        "cube_yaw": rng.uniform(0.0, 2 * np.pi, n),
    }
    noise = rng.normal(0.0, osc_reference.INIT_NOISE_STD, (7, n))
    return out | {f"joint{k + 1}_noise": noise[k] for k in range(7)}


def plain_loop(bound: BoundTask, values, *, robosuite_arithmetic: bool) -> np.ndarray:
    """The episodes one at a time; returns each one's final cube height (m)."""
    model = bound.model
    ids = osc_reference.Ids.of(model)
    grip = model.site(osc_reference.GRIP_SITE).id
    cube = model.body(CUBE_BODY).id
    scratch = mujoco.MjData(model)
    heights = []
    for i in range(len(values["cube_dx"])):
        m, state = bound.episode({k: float(v[i]) for k, v in values.items()}, scratch=scratch)
        if robosuite_arithmetic:
            d = mujoco.MjData(m)
            mujoco.mj_setState(m, d, state, mujoco.mjtState.mjSTATE_FULLPHYSICS)
            controller = osc_reference.start(m, d, ids)
        else:
            episode = PlainEpisode(m, state, operational_space(m, {}))
            d = episode.d
        mujoco.mj_forward(m, d)
        for step in range(scripted.episode_steps(CLOSE_STEPS)):
            action = scripted.action(step, d.site_xpos[grip], d.xpos[cube], CLOSE_STEPS)
            for j in range(N_SUBSTEPS):
                if robosuite_arithmetic:
                    mujoco.mj_step1(m, d)
                    d.ctrl[:] = osc_reference.ctrl(m, d, ids, controller, action, j == 0)
                    mujoco.mj_step2(m, d)
                else:
                    episode.step(action, j == 0, None, 0)
        heights.append(d.xpos[cube][2])
    return np.array(heights)


def engine(bound: BoundTask, values, nthread: int, batch_size: int | None = None) -> np.ndarray:
    out = []
    for batch in iter_batches(
        bound,
        values,
        {"close_steps": CLOSE_STEPS},
        thresholds={},
        nthread=nthread,
        batch_size=batch_size,
    ):
        out.append(batch.outcome["success"])
    return np.concatenate(out)


def timed(fn):
    wall, cpu = time.perf_counter(), time.process_time()
    result = fn()
    return result, time.perf_counter() - wall, time.process_time() - cpu


def robosuite_seconds(values, n: int) -> list[float]:
    states = [
        {
            "cube_dx": float(values["cube_dx"][i]),
            "cube_dy": float(values["cube_dy"][i]),
            "cube_yaw": float(values["cube_yaw"][i]),
            "noise": [float(values[f"joint{k + 1}_noise"][i]) for k in range(7)],
        }
        for i in range(n)
    ]
    with tempfile.NamedTemporaryFile("w", suffix=".json") as f:
        json.dump(states, f)
        f.flush()
        out = subprocess.run(
            [
                sys.executable,
                str(Path(__file__).parent / "robosuite_env_time.py"),
                f.name,
                str(CLOSE_STEPS),
            ],
            check=True,
            capture_output=True,
            text=True,
            cwd=REPO_ROOT,
        )
    return json.loads(out.stdout.strip().splitlines()[-1])


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--episodes", type=int, default=20)
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--robosuite", action="store_true", help="also time robosuite's env")
    parser.add_argument(
        "--batch",
        type=int,
        nargs="*",
        default=[],
        help=f"also time the engine on 1 thread in batches of these sizes (its own: "
        f"{LOW_LEVEL_BATCH})",
    )
    args = parser.parse_args()
    task = load_task(TASK)
    bound = BoundTask.of(task, load_model(task.model))
    values = draw_states(args.episodes)
    n = args.episodes
    runs = {
        "plain loop, robosuite's arithmetic": lambda: plain_loop(
            bound, values, robosuite_arithmetic=True
        ),
        "plain loop, the engine's controller alone": lambda: plain_loop(
            bound, values, robosuite_arithmetic=False
        ),
        "engine, 1 thread": lambda: engine(bound, values, 1),
        "engine, 2 threads": lambda: engine(bound, values, 2),
    }
    for size in args.batch:
        runs[f"engine, 1 thread, batches of {size}"] = partial(engine, bound, values, 1, size)
    wall = {name: [] for name in runs}
    cpu = {name: [] for name in runs}
    robosuite = []  # per repeat: the median of its episodes' CPU seconds
    for repeat in range(args.repeats):
        order = list(runs) if repeat % 2 == 0 else list(reversed(runs))
        if args.robosuite and repeat % 2 == 1:
            robosuite.append(statistics.median(robosuite_seconds(values, n)))
        for name in order:
            _, w, c = timed(runs[name])
            wall[name].append(w)
            cpu[name].append(c)
        if args.robosuite and repeat % 2 == 0:
            robosuite.append(statistics.median(robosuite_seconds(values, n)))
    print(
        f"{n} episodes of {scripted.episode_steps(CLOSE_STEPS) * N_SUBSTEPS} physics steps, "
        f"{args.repeats} repeats (medians)"
    )
    for name in runs:
        print(
            f"  {name:45s} {statistics.median(cpu[name]) / n:7.3f} s CPU/episode  "
            f"{statistics.median(wall[name]):7.2f} s wall"
        )
    baseline = min(
        ("plain loop, robosuite's arithmetic", "plain loop, the engine's controller alone"),
        key=lambda name: statistics.median(wall[name]),
    )
    for name in ("engine, 1 thread", "engine, 2 threads"):
        ratios = [b / e for b, e in zip(wall[baseline], wall[name], strict=True)]
        print(
            f"  {name}: {statistics.median(ratios):.2f}x the faster plain loop's wall "
            f"({min(ratios):.2f}-{max(ratios):.2f})"
        )
    if args.robosuite:
        ratios = [r / (c / n) for r, c in zip(robosuite, cpu["engine, 1 thread"], strict=True)]
        print(
            f"  robosuite's env (MuJoCo 3.9.0): {statistics.median(robosuite):.3f} s CPU/episode "
            f"(median of its episodes, then of repeats); the engine on 1 thread "
            f"{statistics.median(ratios):.2f}x less CPU per episode "
            f"({min(ratios):.2f}-{max(ratios):.2f}, paired by repeat)"
        )


if __name__ == "__main__":
    main()
