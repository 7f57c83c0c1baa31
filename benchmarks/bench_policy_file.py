"""Benchmark: the closed-loop engine with a policy file against the per-episode loop a researcher
writes around the same onnxruntime session.

The policy is a tanh MLP (observations -> 64 -> 64 -> 1, random weights, `ctrlrange` scaling)
exported with the `onnx` package, read through its contract (`mjtrial.policy_files.file`). The
baseline is the plain loop: one `MjData` per episode, the session called once per control step
on that episode's observation (a batch of one), `mj_step` in a Python loop in between, the push
set per step, success checked at every step of the last second, nothing recorded. The engine is
what the pipeline calls, `mjtrial.sim.engine.iter_batches` in its batches (`engine.batch_size_for`),
which also records every physics step, replays each batch's first instants in other batches
(`closed_loop.check_replayed`) and computes the task's measures and categories. Episodes: the
cart-pole of `tasks/cartpole_latency/` under its defaults (3 s, a 10 ms control period),
20 ms of sensing latency, its states drawn from the task's ranges.

    python benchmarks/bench_policy_file.py                 # 200 episodes, 5 repeats
    python benchmarks/bench_policy_file.py --episodes 100 --repeats 3 --hidden 256
    python benchmarks/bench_policy_file.py --batch-size 200     # the engine in larger batches
    python benchmarks/bench_policy_file.py --profile            # where the engine's time goes

It prints episodes per second of each, and the engine's speed over the loop's on 1 and 2
threads: the median of the paired ratios over repeats (each repeat runs the loop and the engine
back to back, in an order that flips every repeat), with their range. It also times one
session call per batch size with graph optimizations on and off (`SESSION_SETTINGS`).
With `--profile`, it runs the engine once more on 1 thread under cProfile and splits its time
into onnxruntime's calls, MuJoCo's, and the Python and numpy around them, with the share of the
whole spent replaying instants in other batches (the exact replay's cost, at most half).
"""

from __future__ import annotations

import argparse
import collections
import statistics
import tempfile
import time
from pathlib import Path

import mujoco
import numpy as np
import onnx
import onnxruntime
import yaml
from alternating import print_rates, time_alternating
from onnx import TensorProto, helper, numpy_helper

from mjtrial import REPO_ROOT
from mjtrial.policy_files.file import load_policy_file, policy_task
from mjtrial.sim.engine import batch_size_for, episode_steps, iter_batches
from mjtrial.sim.physics import FULLPHYSICS
from mjtrial.task import BoundTask, load_task

TASK = REPO_ROOT / "tasks" / "cartpole_latency" / "task.py"
CONDITION = {"latency": 0.02}
UPRIGHT, TRACK = 0.25, 1.0  # the task's success test (rad, m) over its last second


def write_mlp(folder: Path, hidden: int) -> Path:
    """A tanh MLP 2 -> hidden -> hidden -> 1 and its contract, in `folder`."""
    rng = np.random.default_rng(0)
    sizes = [2, hidden, hidden, 1]
    nodes, weights, x = [], [], "observations"
    for i, (a, b) in enumerate(zip(sizes[:-1], sizes[1:], strict=True)):
        w = (rng.normal(size=(a, b)) / np.sqrt(a)).astype(np.float32)
        weights += [
            numpy_helper.from_array(w, f"w{i}"),
            numpy_helper.from_array(np.zeros(b, np.float32), f"b{i}"),
        ]
        out = "action" if i == len(sizes) - 2 else f"h{i}"
        nodes += [
            helper.make_node("MatMul", [x, f"w{i}"], [f"m{i}"]),
            helper.make_node("Add", [f"m{i}", f"b{i}"], [f"a{i}"]),
            helper.make_node("Tanh", [f"a{i}"], [out]),
        ]
        x = out
    graph = helper.make_graph(
        nodes,
        "mlp",
        [helper.make_tensor_value_info("observations", TensorProto.FLOAT, ["batch", 2])],
        [helper.make_tensor_value_info("action", TensorProto.FLOAT, ["batch", 1])],
        weights,
    )
    model = helper.make_model(graph, opset_imports=[helper.make_opsetid("", 17)])
    model.ir_version = 10  # onnxruntime 1.31.1 reads IR <= 13
    path = folder / "mlp.onnx"
    onnx.save(model, str(path))
    contract = {
        "task": "cartpole_latency",
        "observations": ["cart_position", "pole_angle"],
        "input": "observations",
        "output": "action",
        "actuators": ["cart_motor"],
        "action_scale": "ctrlrange",
        "control_period": 0.01,
    }
    path.with_suffix(".yaml").write_text(yaml.safe_dump(contract, sort_keys=False))
    return path


def plain_loop(bound: BoundTask, session, values, timing) -> tuple[int, np.ndarray]:
    """The per-episode loop around the session; returns the number of successes and the final
    states (n, nstate)."""
    model = bound.model
    task = bound.task
    pushes = task.controller.pushes(model, values)
    low, high = model.actuator_ctrlrange[0]
    half_span = (high - low) / 2.0  # the contract's scaling, in the engine's arithmetic
    s = timing.steps_per_control
    delay = timing.latency_steps // s  # in control periods
    judged_from = timing.n_steps - round(1.0 / model.opt.timestep)
    n = len(next(iter(values.values())))
    scratch = mujoco.MjData(model)
    successes = 0
    finals = np.empty((n, mujoco.mj_stateSize(model, FULLPHYSICS)))
    for i in range(n):
        m, state = bound.episode({k: float(v[i]) for k, v in values.items()}, scratch=scratch)
        d = mujoco.MjData(m)
        mujoco.mj_setState(m, d, state, FULLPHYSICS)
        measured = collections.deque([d.qpos[:2].copy()] * (delay + 1), maxlen=delay + 1)
        upright = True
        for k in range(timing.n_controls):
            (action,) = session.run(["action"], {"observations": measured[0][None].astype("f4")})
            d.ctrl[0] = min(max(low + (float(action[0, 0]) + 1.0) * half_span, low), high)
            for j in range(k * s, (k + 1) * s):
                pushed = pushes.start[i] <= j < pushes.stop[i]
                d.xfrc_applied[pushes.body] = pushes.wrench[i] if pushed else 0.0
                mujoco.mj_step(m, d)
                if j >= judged_from:
                    upright &= abs(d.qpos[1]) < UPRIGHT and abs(d.qpos[0]) < TRACK
            measured.append(d.qpos[:2].copy())
        successes += upright
        mujoco.mj_getState(m, d, finals[i], FULLPHYSICS)
    return successes, finals


def engine(bound: BoundTask, values, nthread: int, batch_size: int) -> tuple[int, np.ndarray]:
    """The pipeline's engine over the same episodes; returns the number of successes and the
    final states (n, nstate)."""
    thresholds = {t.name: t.default for t in bound.task.thresholds}
    batches = list(
        iter_batches(
            bound, values, CONDITION, thresholds=thresholds, nthread=nthread, batch_size=batch_size
        )
    )
    finals = np.concatenate([b.episodes.physics[:, -1] for b in batches])
    return sum(int(b.outcome["success"].sum()) for b in batches), finals


def call_times(path: Path, batch_size: int) -> None:
    """Median µs of one session call per batch size, graph optimizations on and off."""
    for level in ("ORT_ENABLE_ALL", "ORT_DISABLE_ALL"):
        options = onnxruntime.SessionOptions()
        options.intra_op_num_threads = options.inter_op_num_threads = 1
        options.graph_optimization_level = getattr(onnxruntime.GraphOptimizationLevel, level)
        session = onnxruntime.InferenceSession(str(path), options, ["CPUExecutionProvider"])
        times = []
        for n in sorted({1, batch_size, 200}):
            rows = np.zeros((n, 2), np.float32)
            spent = []
            for _ in range(300):
                t0 = time.perf_counter()
                session.run(["action"], {"observations": rows})
                spent.append(time.perf_counter() - t0)
            times.append(f"{n} rows {statistics.median(spent) * 1e6:.0f} µs")
        print(f"one call, {level}: {', '.join(times)}")


def profile(bound: BoundTask, values, batch_size: int) -> None:
    """Where the engine's time goes, on 1 thread, by cProfile's own times of each function."""
    import cProfile
    import pstats

    profiler = cProfile.Profile()
    profiler.runcall(engine, bound, values, 0, batch_size)
    stats = pstats.Stats(profiler).stats  # (file, line, name) -> (cc, nc, own, cumulative, callers)
    parts = collections.Counter()
    replay = 0.0
    for (file, _, name), (_, _, own, cumulative, _) in stats.items():
        where = f"{file} {name}"
        if "onnxruntime" in where:
            parts["onnxruntime (session calls)"] += own
        elif "mujoco" in where:
            parts["MuJoCo (rollout, state, model calls)"] += own
        else:
            parts["Python and numpy around them"] += own
        if name == "check_replayed":
            replay = max(replay, cumulative)
    total = sum(parts.values())
    print(f"engine profile, 1 thread, {total:.2f} s under cProfile:")
    for part, seconds in parts.most_common():
        print(f"  {part}: {seconds:.2f} s ({seconds / total:.0%})")
    share = replay / total
    print(f"  of the whole, replaying instants in other batches: {replay:.2f} s ({share:.0%})")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--episodes", type=int, default=200)
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--hidden", type=int, default=64, help="width of the MLP's two layers")
    parser.add_argument(
        "--batch-size",
        type=int,
        default=None,
        help="the engine's episodes per batch (default: the pipeline's, `batch_size_for`)",
    )
    parser.add_argument("--profile", action="store_true", help="also split the engine's time")
    args = parser.parse_args()
    task = load_task(TASK)
    folder = Path(tempfile.mkdtemp())
    path = write_mlp(folder, args.hidden)
    policy = load_policy_file(path, task)
    bound = BoundTask.of(policy_task(task, policy))
    params = task.parameters(CONDITION)
    timing = task.controller.timing(bound.model, params)
    batch_size = args.batch_size or batch_size_for(bound.model, episode_steps(bound, CONDITION))
    rng = np.random.default_rng(0)
    n = args.episodes
    values = {p.name: rng.uniform(p.low, p.high, n) for p in task.state_parameters}
    print(
        f"{n} cart-pole episodes, {timing.n_controls} control instants each, latency "
        f"{CONDITION['latency'] * 1e3:.0f} ms; MLP 2-{args.hidden}-{args.hidden}-1 through "
        f"onnxruntime {onnxruntime.__version__}; engine batches of {batch_size}; "
        f"{args.repeats} repeats"
    )
    call_times(path, batch_size)
    outcome, seconds, ratios = time_alternating(
        lambda: plain_loop(bound, policy.session, values, timing),
        lambda t: engine(bound, values, t if t > 1 else 0, batch_size),
        args.repeats,
    )
    same = np.array_equal(outcome["loop"][1], outcome["engine"][1])
    print(
        f"successes: loop {outcome['loop'][0]}, engine {outcome['engine'][0]} (of {n}); final "
        f"states {'equal bit for bit' if same else 'DIFFER'} (must be equal)"
    )
    print_rates(n, seconds, ratios)
    if args.profile:
        profile(bound, values, batch_size)


if __name__ == "__main__":
    main()
