"""What both cart-pole policy producers share: the development states and the benchmark's
condition, episodes run by mjtrial's engine with a policy in place of the task's LQR, the
encoder front end (finite-difference velocities carried in a recurrent state) in numpy and as
ONNX nodes, an onnxruntime policy to check an exported file, and the contract.

The policies read the task's encoder observations [cart_position, pole_angle] only: their
velocities are finite differences between control instants, computed inside the graph from a
recurrent state `memory` = [previous cart_position, previous pole_angle, started] that the
runtime feeds back and resets to zeros at each episode's start, so the first instant's
velocity is zero, as the designed LQR's (`mjtrial.sim.controllers.EncoderFeedback`).
"""

from __future__ import annotations

import dataclasses
import importlib.util
from collections.abc import Callable, Mapping
from pathlib import Path
from types import ModuleType

import mujoco
import numpy as np
import yaml

from mjtrial.sim.closed_loop import BatchPolicy, replay_splits
from mjtrial.sim.engine import iter_batches
from mjtrial.sim.physics import STATE_QPOS
from mjtrial.stages.stamping import config_slice
from mjtrial.stages.states import draw_states
from mjtrial.task import BoundTask, Task
from mjtrial.task.load import load_task

REPO_ROOT = Path(__file__).resolve().parents[1]
EXPERIMENT = REPO_ROOT / "config" / "cartpole_latency.yaml"
BENCHMARK = REPO_ROOT / "config" / "benchmark.yaml"
TASK_NAME = "cartpole_latency"

# The graph's interface (the contract's names).
OBSERVATIONS = ("cart_position", "pole_angle")
INPUT, OUTPUT = "observations", "action"
MEMORY_IN, MEMORY_OUT = "memory_in", "memory_out"
MEMORY_SIZE = len(OBSERVATIONS) + 1  # the previous observations and a started flag
ACTUATORS = ("cart_motor",)
# Features [x, angle, x rate, angle rate] in units of the success test's limits (1 m, 0.25 rad)
# and 1 m/s, 1 rad/s: each of order one for the network.
FEATURE_SCALE = np.array([1.0, 0.25, 1.0, 1.0])
# onnxruntime 1.31.1 reads IR versions up to 13; onnx 1.23.2 writes 14 by default.
OPSET, IR_VERSION = 17, 8


def experiment() -> dict:
    return yaml.safe_load(EXPERIMENT.read_text())


def benchmark_condition() -> dict[str, float]:
    """The protocol parameters every method runs with on this task in the benchmark."""
    config = yaml.safe_load(BENCHMARK.read_text())
    return {k: float(v) for k, v in config["benchmark"]["tasks"][TASK_NAME]["condition"].items()}


def development_states() -> dict[str, np.ndarray]:
    """The task's development states (`states.development_seed`), drawn as the pipeline draws
    them (refused if they overlap the evaluation states): state parameter -> (n,)."""
    table = draw_states(config_slice("states", experiment()), repo_root=REPO_ROOT)[1]
    return {c: table.column(c).to_numpy() for c in table.column_names if c != "state_id"}


def control_period() -> float:
    """The task's control period under the benchmark's condition, s: what the policies are
    trained at (their graphs' finite differences divide by it)."""
    return float(bound_task().task.parameters(benchmark_condition())["control_period"])


def task_module() -> ModuleType:
    """The task file as a module: its design constants (the LQR's gain, the track's length)."""
    path = REPO_ROOT / "tasks" / TASK_NAME / "task.py"
    spec = importlib.util.spec_from_file_location("cartpole_latency_task", path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def bound_task() -> BoundTask:
    return BoundTask.of(load_task(REPO_ROOT / "tasks" / TASK_NAME / "task.py"))


def with_policy(bound: BoundTask, make: Callable[[mujoco.MjModel], BatchPolicy]) -> BoundTask:
    """The task with `make(model)` as its policy instead of the designed LQR."""
    controller = dataclasses.replace(bound.task.controller, policy=lambda m, params: make(m))
    task: Task = dataclasses.replace(bound.task, controller=controller)
    return dataclasses.replace(bound, task=task)


def thresholds(bound: BoundTask) -> dict[str, float]:
    given = experiment().get("failure_taxonomy", {})
    return {t.name: float(given.get(t.name, t.default)) for t in bound.task.thresholds}


def run(
    bound: BoundTask,
    values: Mapping[str, np.ndarray],
    rows: np.ndarray | None = None,
    *,
    batch_size: int = 16,
    replay_check: bool = True,
) -> tuple[np.ndarray, np.ndarray]:
    """Run the episodes of `values` (the rows `rows`, default all) under the benchmark's
    condition with the engine. Returns (success, alive): per episode (n,) bool and the
    fraction of its physics steps before the pole passed `fall_angle` or the cart left the
    track (1.0 if neither), a graded score for episodes that fail. `replay_check` off: a
    search's scores (`mjtrial.sim.engine.iter_batches`)."""
    if rows is not None:
        values = {k: np.asarray(v)[rows] for k, v in values.items()}
    limits = thresholds(bound)
    track = task_module().TRACK
    m = bound.model
    qpos = [STATE_QPOS + m.jnt_qposadr[m.joint(name).id] for name in ("cart_slide", "pole_hinge")]
    success, alive = [], []
    for batch in iter_batches(
        bound,
        values,
        benchmark_condition(),
        thresholds=limits,
        batch_size=batch_size,
        replay_check=replay_check,
    ):
        x, angle = (batch.episodes.physics[:, :, i] for i in qpos)
        down = (np.abs(angle) >= limits["fall_angle"]) | (np.abs(x) >= track)
        first = np.where(down.any(axis=1), down.argmax(axis=1), down.shape[1])
        success.append(batch.outcome["success"])
        alive.append(first / down.shape[1])
    return np.concatenate(success), np.concatenate(alive)


# ---------------------------------------------------------------------------------------------
# The encoder front end, in numpy (training) and as ONNX nodes (export)
# ---------------------------------------------------------------------------------------------


class EncoderFeatures:
    """Per-episode memory of the previous observations: features (n, 4) from observations
    (n, 2), row by row in float64, as the exported graph computes them in float32."""

    def __init__(self, period: float) -> None:
        self.period = float(period)
        self.memory = np.zeros((0, MEMORY_SIZE))

    def reset(self, n_episodes: int) -> None:
        self.memory = np.zeros((n_episodes, MEMORY_SIZE))

    def __call__(self, observations: np.ndarray) -> np.ndarray:
        y = np.asarray(observations, dtype=np.float64)
        previous, started = self.memory[:, :-1], self.memory[:, -1:]
        velocity = (y - previous) / self.period * started
        self.memory = np.concatenate([y, np.ones((len(y), 1))], axis=1)
        return np.concatenate([y, velocity], axis=1) / FEATURE_SCALE


def tensor(name: str, width: int):
    """A graph input or output: float32 (batch, width), the batch dimension symbolic."""
    from onnx import TensorProto, helper  # a training dependency ([train])

    return helper.make_tensor_value_info(name, TensorProto.FLOAT, ["batch", width])


def front_end(period: float, features: str):
    """ONNX nodes, initializers and graph inputs computing `features` (batch, 4) and
    `memory_out` from `observations` and `memory_in` (see the module's docstring)."""
    from onnx import TensorProto, helper, numpy_helper  # a training dependency ([train])

    def constant(name: str, value) -> object:
        return numpy_helper.from_array(np.asarray(value, dtype=np.float32), name)

    def int64s(name: str, value) -> object:
        return numpy_helper.from_array(np.asarray(value, dtype=np.int64), name)

    initializers = [
        int64s("first_two", [0]),
        int64s("two", [len(OBSERVATIONS)]),
        int64s("three", [MEMORY_SIZE]),
        int64s("columns", [1]),
        int64s("one_column", [1]),
        constant("period", period),
        constant("feature_scale", FEATURE_SCALE[None, :]),
    ]
    n = helper.make_node
    nodes = [
        n("Slice", [MEMORY_IN, "first_two", "two", "columns"], ["previous"]),
        n("Slice", [MEMORY_IN, "two", "three", "columns"], ["started"]),
        n("Sub", [INPUT, "previous"], ["difference"]),
        n("Div", ["difference", "period"], ["rate"]),
        n("Mul", ["rate", "started"], ["velocity"]),
        n("Concat", [INPUT, "velocity"], ["raw_features"], axis=1),
        n("Div", ["raw_features", "feature_scale"], [features]),
        n("Shape", [INPUT], ["batch_size"], end=1),
        n("Concat", ["batch_size", "one_column"], ["ones_shape"], axis=0),
        n(
            "ConstantOfShape",
            ["ones_shape"],
            ["ones"],
            value=helper.make_tensor("one", TensorProto.FLOAT, [1], [1.0]),
        ),
        n("Concat", [INPUT, "ones"], [MEMORY_OUT], axis=1),
    ]
    inputs = [tensor(INPUT, len(OBSERVATIONS)), tensor(MEMORY_IN, MEMORY_SIZE)]
    return nodes, initializers, inputs


def dense(h: np.ndarray, w: np.ndarray, b: np.ndarray) -> np.ndarray:
    """h W + b (float64), each row from that row alone: a sum over inputs in a fixed order, not
    a matrix product, whose summation order may depend on the batch (the engine checks)."""
    z = np.broadcast_to(np.asarray(b, dtype=np.float64).reshape(1, -1), (len(h), w.shape[1]))
    z = z.copy()
    for j in range(w.shape[0]):
        z += h[:, j : j + 1] * np.asarray(w[j], dtype=np.float64)[None, :]
    return z


def action_to_ctrl(action: np.ndarray, ctrl_range: np.ndarray) -> np.ndarray:
    """The contract's `action_scale: ctrlrange`: [-1, 1] onto each actuator's range, clipped."""
    low, high = np.asarray(ctrl_range, dtype=np.float64).T
    mid, half = (high + low) / 2, (high - low) / 2
    return np.clip(mid + half * np.asarray(action, dtype=np.float64), low, high)


# ---------------------------------------------------------------------------------------------
# Checking an exported file: the same episodes through onnxruntime
# ---------------------------------------------------------------------------------------------


class OnnxPolicy:
    """An exported file as the engine's policy, through onnxruntime on one thread: memory
    zeros at each reset, then the graph's `memory_out` fed back."""

    def __init__(self, path: Path, model: mujoco.MjModel) -> None:
        import onnxruntime as ort  # a check of the export, not the runtime's integration

        options = ort.SessionOptions()
        options.intra_op_num_threads = options.inter_op_num_threads = 1
        self.session = ort.InferenceSession(str(path), options, providers=["CPUExecutionProvider"])
        self.ctrl_range = model.actuator_ctrlrange[[model.actuator(a).id for a in ACTUATORS]]
        self.memory = np.zeros((0, MEMORY_SIZE), dtype=np.float32)

    def reset(self, n_episodes: int) -> None:
        self.memory = np.zeros((n_episodes, MEMORY_SIZE), dtype=np.float32)

    def __call__(self, observations: np.ndarray) -> np.ndarray:
        feed = {INPUT: np.asarray(observations, dtype=np.float32), MEMORY_IN: self.memory}
        action, self.memory = self.session.run([OUTPUT, MEMORY_OUT], feed)
        return action_to_ctrl(action, self.ctrl_range)


class Recorder:
    """A policy whose calls are kept: each call's observations and controls, one list per
    reset (the engine's replays of a batch start lists of their own)."""

    def __init__(self, policy: BatchPolicy) -> None:
        self.policy = policy
        self.calls: list[list[tuple[np.ndarray, np.ndarray]]] = []

    def reset(self, n_episodes: int) -> None:
        self.policy.reset(n_episodes)
        self.calls.append([])

    def __call__(self, observations: np.ndarray) -> np.ndarray:
        ctrl = self.policy(observations)
        self.calls[-1].append((np.array(observations), np.array(ctrl)))
        return ctrl

    def episodes(self, n_controls: int) -> list[list[tuple[np.ndarray, np.ndarray]]]:
        """The calls of whole batches of episodes (`n_controls` instants from a reset), less the
        engine's replays: after a batch of n > 1 rows it replays each row alone, from a reset of
        its own (`mjtrial.sim.closed_loop.replay_splits`), n lists that repeat what is recorded."""
        out, replays = [], 0
        for calls in self.calls:
            if replays:
                replays -= 1
                continue
            if len(calls) == n_controls:
                out.append(calls)
                rows = len(calls[0][0])
                replays = len(replay_splits(rows))
        return out


def check_export(
    path: Path, trained: Callable[[mujoco.MjModel], BatchPolicy]
) -> dict[str, float | int]:
    """An exported file through onnxruntime against the training-time forward pass `trained`,
    on every development state: each one's success rate, the outcomes that differ, and the
    largest difference of their controls (N) on the observations the exported file saw."""
    bound = bound_task()
    values = development_states()
    params = bound.task.parameters(benchmark_condition())
    n_controls = bound.task.controller.timing(bound.model, params).n_controls
    exported = Recorder(OnnxPolicy(path, bound.model))
    exported_success, _ = run(with_policy(bound, lambda m: exported), values)
    trained_success, _ = run(with_policy(bound, trained), values)
    largest = 0.0
    policy = trained(bound.model)
    for calls in exported.episodes(n_controls):
        policy.reset(len(calls[0][0]))
        for observations, ctrl in calls:
            largest = max(largest, float(np.abs(policy(observations) - ctrl).max()))
    return {
        "onnxruntime_success_rate": float(exported_success.mean()),
        "float64_success_rate": float(trained_success.mean()),
        "outcomes_differing": int((exported_success != trained_success).sum()),
        "largest_ctrl_difference": float(f"{largest:.3g}"),
    }


def trained_on() -> str:
    """Where a producer trained, for its contract's `producer` text."""
    latency = benchmark_condition()["latency"]
    seed = experiment()["states"]["development_seed"]
    return f"the development states (seed {seed}) at {latency * 1000:g} ms latency"


def versions(*packages: str) -> str:
    """`name version, ...` of the packages a producer used, for its contract's `producer`."""
    import importlib.metadata

    return ", ".join(f"{p} {importlib.metadata.version(p)}" for p in packages)


def write_contract(folder: Path, *, period: float, producer: str) -> None:
    """The folder's `policy.yaml` (the policy-file contract), in a fixed key order."""
    contract = {
        "task": TASK_NAME,
        "observations": list(OBSERVATIONS),
        "input": INPUT,
        "output": OUTPUT,
        "actuators": list(ACTUATORS),
        "action_scale": "ctrlrange",
        "control_period": float(period),
        "recurrent": [{"input": MEMORY_IN, "output": MEMORY_OUT, "size": MEMORY_SIZE}],
        "producer": producer,
    }
    text = yaml.safe_dump(contract, sort_keys=False, width=100)
    (Path(folder) / "policy.yaml").write_text(text)
