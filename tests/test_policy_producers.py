"""The shipped cart-pole policy files (policies/cartpole_mlp, policies/cartpole_bc): their
contracts and graphs, what their graphs compute against a plain numpy reference, their
episodes in the engine (every batch's replay check, the same outcomes in batches of other
sizes, the development success their training recorded), and their training scripts: the
behaviour cloning reproduces the committed files byte for byte, and a reduced CMA-ES run is
deterministic (the full one takes minutes; its command is in its README)."""

from __future__ import annotations

import hashlib
import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import onnx
import pytest
import yaml
from conftest import REPO_ROOT

pytestmark = pytest.mark.end_to_end

FOLDERS = ("cartpole_mlp", "cartpole_bc")
SEEDS = (1, 2, 3, 4, 5)
FILES = [REPO_ROOT / "policies" / f / f"seed-{k}.onnx" for f in FOLDERS for k in SEEDS]


def ids(path: Path) -> str:
    return f"{path.parent.name}/{path.name}"


def sha256(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def train(folder: str, out: Path, *args: str) -> None:
    done = subprocess.run(
        [sys.executable, "-m", f"policies.{folder}.train", "--out", str(out), "--no-check", *args],
        cwd=REPO_ROOT,
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert done.returncode == 0, done.stderr[-2000:]


@pytest.mark.parametrize("folder", FOLDERS)
def test_contract_names_the_tasks_encoders_and_motor(folder):
    from mjtrial.task import BoundTask
    from mjtrial.task.load import load_task

    contract = yaml.safe_load((REPO_ROOT / "policies" / folder / "policy.yaml").read_text())
    task = load_task(REPO_ROOT / "tasks" / "cartpole_latency" / "task.py")
    model = BoundTask.of(task).model
    assert contract["task"] == task.name
    sources = {o.name: o.source for o in task.observations}
    assert contract["observations"] == ["cart_position", "pole_angle"]
    assert all(sources[name] is not None for name in contract["observations"])  # not privileged
    assert [model.actuator(a).name for a in contract["actuators"]] == ["cart_motor"]
    assert contract["control_period"] == task.parameters({})["control_period"]
    assert contract["action_scale"] == "ctrlrange"
    assert contract["recurrent"] == [{"input": "memory_in", "output": "memory_out", "size": 3}]
    assert (contract["input"], contract["output"]) == ("observations", "action")


@pytest.mark.parametrize("path", FILES, ids=ids)
def test_graph_follows_the_contract(path):
    model = onnx.load(str(path))
    onnx.checker.check_model(model, full_check=True)
    assert model.ir_version <= 13  # onnxruntime 1.31.1 refuses 14, onnx 1.23.2's default
    assert [(o.domain, o.version <= 17) for o in model.opset_import] == [("", True)]

    def signature(values):
        return [
            (
                v.name,
                v.type.tensor_type.elem_type,
                [d.dim_param or d.dim_value for d in v.type.tensor_type.shape.dim],
            )
            for v in values
        ]

    float32 = onnx.TensorProto.FLOAT
    assert signature(model.graph.input) == [
        ("observations", float32, ["batch", 2]),
        ("memory_in", float32, ["batch", 3]),
    ]
    assert signature(model.graph.output) == [
        ("action", float32, ["batch", 1]),
        ("memory_out", float32, ["batch", 3]),
    ]
    assert path.stat().st_size < 8192  # kilobytes


def reference_actions(path: Path, observations: np.ndarray) -> np.ndarray:
    """The file's network by hand in float64 from its weights, over a sequence of control
    instants (k, n, 2): velocities by finite differences over the 10 ms period, zero at the
    first instant; features scaled by (1 m, 0.25 rad, 1 m/s, 1 rad/s)."""
    weights = {
        t.name: onnx.numpy_helper.to_array(t) for t in onnx.load(str(path)).graph.initializer
    }
    if "w1" in weights:  # CMA-ES's MLP: tanh output
        layers, last = [("w1", "b1"), ("w2", "b2")], np.tanh
    else:  # skl2onnx's MLPRegressor: identity output
        layers, last = [("coefficient", "intercepts"), ("coefficient1", "intercepts1")], None
    out, previous = [], None
    for y in observations:
        velocity = np.zeros_like(y) if previous is None else (y - previous) / 0.01
        previous = y
        h = np.concatenate([y, velocity], axis=1) / [1.0, 0.25, 1.0, 1.0]
        for i, (w, b) in enumerate(layers):
            h = h @ weights[w].astype(np.float64) + weights[b].astype(np.float64)
            h = np.tanh(h) if i < len(layers) - 1 or last else h
        out.append(h)
    return np.stack(out)


@pytest.mark.parametrize("path", FILES, ids=ids)
def test_graph_computes_its_network_on_finite_differences(path):
    import onnxruntime as ort

    session = ort.InferenceSession(str(path), providers=["CPUExecutionProvider"])
    rng = np.random.default_rng(3)
    observations = np.cumsum(rng.normal(0, 0.01, (6, 7, 2)), axis=0).astype(np.float32)
    memory = np.zeros((7, 3), dtype=np.float32)
    actions = []
    for y in observations:
        action, memory = session.run(None, {"observations": y, "memory_in": memory})
        np.testing.assert_array_equal(memory, np.concatenate([y, np.ones((7, 1))], axis=1))
        actions.append(action)
    expected = reference_actions(path, observations.astype(np.float64))
    np.testing.assert_allclose(np.stack(actions), expected, atol=2e-5)


@pytest.fixture(scope="module")
def development():
    from policies import cartpole

    return cartpole.bound_task(), cartpole.development_states()


@pytest.mark.parametrize("path", FILES, ids=ids)
def test_shipped_network_balances_as_trained_whatever_the_batch(path, development):
    """Every development state in batches of 200 (the engine replays each batch's first
    instants in other batches and raises if a row differs), then a few in batches of 3: the
    same trajectories bit for bit; the rate is the one the training recorded."""
    from mjtrial.sim.engine import iter_batches
    from policies import cartpole

    bound, values = development
    runs = cartpole.with_policy(bound, lambda m: cartpole.OnnxPolicy(path, m))
    success, _ = cartpole.run(runs, values, batch_size=200)
    record = json.loads((path.parent / "training.json").read_text())
    seeds = record if isinstance(record, list) else record["seeds"]
    (trained,) = [r for r in seeds if f"seed-{r['seed']}.onnx" == path.name]
    assert success.mean() == trained["onnxruntime_success_rate"]
    some = {k: v[:7] for k, v in values.items()}
    condition = cartpole.benchmark_condition()
    limits = cartpole.thresholds(bound)
    physics = [
        np.concatenate(
            [
                b.episodes.physics
                for b in iter_batches(runs, some, condition, thresholds=limits, batch_size=size)
            ]
        )
        for size in (7, 3)
    ]
    np.testing.assert_array_equal(physics[0], physics[1])


def test_behaviour_cloning_reproduces_the_shipped_files(tmp_path):
    train("cartpole_bc", tmp_path)
    shipped = REPO_ROOT / "policies" / "cartpole_bc"
    for name in [*(f"seed-{k}.onnx" for k in SEEDS), "policy.yaml"]:
        assert sha256(tmp_path / name) == sha256(shipped / name), name


def test_evolution_strategy_is_deterministic(tmp_path):
    """The smallest budget (one generation and the finalists) twice: the same bytes."""
    for run in ("a", "b"):
        train("cartpole_mlp", tmp_path / run, "--seeds", "2", "--budget", "840")
    assert sha256(tmp_path / "a" / "seed-2.onnx") == sha256(tmp_path / "b" / "seed-2.onnx")
    shipped = REPO_ROOT / "policies" / "cartpole_mlp" / "policy.yaml"
    assert (tmp_path / "a" / "policy.yaml").read_text() == shipped.read_text()
