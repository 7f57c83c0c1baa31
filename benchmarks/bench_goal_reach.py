"""Benchmark: a goal-conditioned closed loop, goals read as episode values, against the
per-episode loop a researcher writes for it.

Episodes: `tasks/reacher_goal/` (dm_control's reacher as shipped; a goal drawn per episode moves
its target geom; the policy is told the goal), 1.1 s, 60 ms of sensing latency. The baseline is
the plain loop: one model whose goal is set in place for each episode, one `MjData`, the task's own
policy called once per control step on that episode's observation (encoder angles as they were
60 ms ago, the goal), `mj_step` in a Python loop in between, the success test (fingertip within
the tolerance at every step of the last 0.5 s) evaluated as the steps go, nothing recorded. The
engine is what the rollout stage runs (`mjtrial.sim.engine.iter_batches`: per-episode models, the
policy on lockstep batches, every physics step's state kept, the task's measures and failure
categories). Both must give the same successes.

    python benchmarks/bench_goal_reach.py                 # 200 episodes, 5 repeats
    python benchmarks/bench_goal_reach.py --episodes 100 --repeats 3

It prints episodes per second of each and the engine's speed over the loop (the median of the
paired ratios over repeats, run back to back in an order that flips every repeat, with their
range), on 1 thread.
"""

from __future__ import annotations

import argparse
import copy
import importlib.util
import statistics
import time

import mujoco
import numpy as np

from mjtrial import REPO_ROOT
from mjtrial.sim.engine import iter_batches
from mjtrial.task import BoundTask, load_task

TASK_FILE = REPO_ROOT / "tasks" / "reacher_goal" / "task.py"
CONDITION = {"latency": 0.06, "kp": 1.0, "duration": 1.1, "control_period": 0.02}


def task_module():
    spec = importlib.util.spec_from_file_location("reacher_goal_bench", TASK_FILE)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def plain_loop(module, model: mujoco.MjModel, values: dict[str, np.ndarray]) -> np.ndarray:
    """Each episode with its own model copy and MjData, the policy once per control step."""
    per_control = round(CONDITION["control_period"] / model.opt.timestep)
    latency = round(CONDITION["latency"] / model.opt.timestep)
    n_controls = round(CONDITION["duration"] / CONDITION["control_period"])
    judged_from = n_controls * per_control - round(module.JUDGED_OVER / model.opt.timestep)
    target = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_GEOM, "target")
    l1, l2 = module.link_lengths(model)
    n = len(values["goal_x"])
    success = np.zeros(n, dtype=bool)
    m = copy.copy(model)  # one model, its goal set in place for each episode: no copy per episode
    d = mujoco.MjData(m)
    for i in range(n):
        goal = np.array([values["goal_x"][i], values["goal_y"][i]])
        m.geom_pos[target, :2] = goal
        mujoco.mj_resetData(m, d)
        d.qpos[0] += values["shoulder_start"][i]
        d.qpos[1] += values["wrist_start"][i]
        policy = module.JointPD(model, CONDITION["kp"], CONDITION["control_period"])
        policy.reset(1)
        history = [d.qpos[:2].copy()]
        ok = True
        for k in range(n_controls):
            seen = history[max(0, k * per_control - latency)]
            d.ctrl[:] = policy(np.array([[seen[0], seen[1], goal[0], goal[1]]]))[0]
            for _ in range(per_control):
                mujoco.mj_step(m, d)
                history.append(d.qpos[:2].copy())
                if len(history) - 1 > judged_from:
                    q0, q1 = d.qpos[0], d.qpos[0] + d.qpos[1]
                    tip = np.array(
                        [l1 * np.cos(q0) + l2 * np.cos(q1), l1 * np.sin(q0) + l2 * np.sin(q1)]
                    )
                    ok = ok and np.linalg.norm(tip - goal) < module.TOLERANCE
        success[i] = ok
    return success


def engine(bound: BoundTask, values: dict[str, np.ndarray]) -> np.ndarray:
    return np.concatenate(
        [b.outcome["success"] for b in iter_batches(bound, values, CONDITION, thresholds={})]
    )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--episodes", type=int, default=200)
    parser.add_argument("--repeats", type=int, default=5)
    args = parser.parse_args()
    module, bound = task_module(), BoundTask.of(load_task(TASK_FILE))
    rng = np.random.default_rng(0)
    values = {
        p.name: rng.uniform(p.low, p.high, args.episodes) for p in bound.task.state_parameters
    }
    loop_success, engine_success = plain_loop(module, bound.model, values), engine(bound, values)
    if not np.array_equal(loop_success, engine_success):
        raise SystemExit("the engine and the plain loop disagree on successes")
    times = {"loop": [], "engine": []}
    for r in range(args.repeats):
        order = ("loop", "engine") if r % 2 == 0 else ("engine", "loop")
        for name in order:
            start = time.perf_counter()
            plain_loop(module, bound.model, values) if name == "loop" else engine(bound, values)
            times[name].append(time.perf_counter() - start)
    ratios = [loop / eng for loop, eng in zip(times["loop"], times["engine"], strict=True)]
    n = args.episodes
    print(f"{n} episodes, {int(engine_success.sum())} successes in both, {args.repeats} repeats")
    print(f"plain loop: {n / statistics.median(times['loop']):.0f} episodes/s")
    print(f"engine:     {n / statistics.median(times['engine']):.0f} episodes/s")
    print(
        f"engine / loop: {statistics.median(ratios):.2f}x "
        f"(range {min(ratios):.2f}-{max(ratios):.2f})"
    )


if __name__ == "__main__":
    main()
