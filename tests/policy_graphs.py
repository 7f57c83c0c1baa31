"""Small ONNX graphs for the policy-file tests, built with `onnx.helper` (IR version 10, which
onnxruntime 1.31.1 reads; onnx 1.23.2 writes 14 by default)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import onnx
import yaml
from onnx import TensorProto, helper, numpy_helper

IR_VERSION = 10
OPSET = 17
CARTPOLE = "cartpole_latency"


def save(graph: onnx.GraphProto, path: Path, *, ir_version: int = IR_VERSION) -> Path:
    model = helper.make_model(graph, opset_imports=[helper.make_opsetid("", OPSET)])
    model.ir_version = ir_version
    onnx.save(model, str(path))
    return path


def tensor(name: str, width: int, *, batch: str | int = "batch", dtype=TensorProto.FLOAT):
    return helper.make_tensor_value_info(name, dtype, [batch, width])


def tanh_mlp(sizes: list[int], *, seed: int = 0, batch: str | int = "batch", dtype=None):
    """A tanh MLP `sizes[0] -> ... -> sizes[-1]` with random weights, tanh on every layer
    (the output in [-1, 1], for `action_scale: ctrlrange`); input "observations", output
    "action"."""
    rng = np.random.default_rng(seed)
    dtype = dtype or TensorProto.FLOAT
    np_dtype = np.float32 if dtype == TensorProto.FLOAT else np.float64
    nodes, weights, x = [], [], "observations"
    for i, (a, b) in enumerate(zip(sizes[:-1], sizes[1:], strict=True)):
        w = (rng.normal(size=(a, b)) / np.sqrt(a)).astype(np_dtype)
        bias = (rng.normal(size=b) * 0.1).astype(np_dtype)
        weights += [numpy_helper.from_array(w, f"w{i}"), numpy_helper.from_array(bias, f"b{i}")]
        out = "action" if i == len(sizes) - 2 else f"h{i}"
        nodes += [
            helper.make_node("MatMul", [x, f"w{i}"], [f"m{i}"]),
            helper.make_node("Add", [f"m{i}", f"b{i}"], [f"a{i}"]),
            helper.make_node("Tanh", [f"a{i}"], [out]),
        ]
        x = out
    return helper.make_graph(
        nodes,
        "mlp",
        [tensor("observations", sizes[0], batch=batch, dtype=dtype)],
        [tensor("action", sizes[-1], batch=batch, dtype=dtype)],
        weights,
    )


def encoder_lqr(gain: np.ndarray, period: float):
    """The cart-pole's `EncoderFeedback` as a graph: u = -K [y, v], v = (y - y_prev) / period
    from a recurrent state [y_prev, started] (zeros at an episode's start: v = 0 at its first
    instant, as the task's policy). Raw output (MuJoCo clamps ctrl to the motor's range)."""
    k = np.asarray(gain, dtype=np.float32).reshape(1, 4)
    consts = {
        "minus_k_t": -k.T,
        "inv_period": np.array(1.0 / period, dtype=np.float32),
        "one": np.array(1.0, dtype=np.float32),
        "zero": np.array(0.0, dtype=np.float32),
        "s0": np.array([0], dtype=np.int64),
        "s2": np.array([2], dtype=np.int64),
        "s3": np.array([3], dtype=np.int64),
        "ax1": np.array([1], dtype=np.int64),
    }
    nodes = [
        helper.make_node("Slice", ["memory_in", "s0", "s2", "ax1"], ["previous"]),
        helper.make_node("Slice", ["memory_in", "s2", "s3", "ax1"], ["started"]),
        helper.make_node("Sub", ["observations", "previous"], ["dy"]),
        helper.make_node("Mul", ["dy", "started"], ["dy_started"]),
        helper.make_node("Mul", ["dy_started", "inv_period"], ["velocity"]),
        helper.make_node("Concat", ["observations", "velocity"], ["state"], axis=1),
        helper.make_node("MatMul", ["state", "minus_k_t"], ["action"]),
        helper.make_node("Mul", ["started", "zero"], ["zeros"]),
        helper.make_node("Add", ["zeros", "one"], ["ones"]),
        helper.make_node("Concat", ["observations", "ones"], ["memory_out"], axis=1),
    ]
    return helper.make_graph(
        nodes,
        "encoder_lqr",
        [tensor("observations", 2), tensor("memory_in", 3)],
        [tensor("action", 1), tensor("memory_out", 3)],
        [numpy_helper.from_array(v, n) for n, v in consts.items()],
    )


def sqrt_of_angle():
    """ctrl 0 while the pole angle (column 1) is >= 0, NaN once it is negative."""
    nodes = [
        helper.make_node("Slice", ["observations", "s1", "s2", "ax1"], ["angle"]),
        helper.make_node("Sqrt", ["angle"], ["root"]),
        helper.make_node("Mul", ["root", "zero"], ["action"]),
    ]
    consts = {
        "s1": np.array([1], dtype=np.int64),
        "s2": np.array([2], dtype=np.int64),
        "ax1": np.array([1], dtype=np.int64),
        "zero": np.array(0.0, dtype=np.float32),
    }
    return helper.make_graph(
        nodes,
        "sqrt_of_angle",
        [tensor("observations", 2)],
        [tensor("action", 1)],
        [numpy_helper.from_array(v, n) for n, v in consts.items()],
    )


def contract(**changes) -> dict:
    """The cart-pole contract of `tanh_mlp([2, ..., 1])`, with `changes`."""
    out = {
        "task": CARTPOLE,
        "observations": ["cart_position", "pole_angle"],
        "input": "observations",
        "output": "action",
        "actuators": ["cart_motor"],
        "action_scale": "ctrlrange",
        "control_period": 0.01,
        "producer": "tests/policy_graphs.py",
    }
    return {**out, **changes}


def write(folder: Path, name: str, graph, **changes) -> Path:
    """`<name>.onnx` and its contract `<name>.yaml` in `folder`; `ir_version` among `changes`
    sets the file's IR version."""
    folder.mkdir(parents=True, exist_ok=True)
    ir_version = changes.pop("ir_version", IR_VERSION)
    path = save(graph, folder / f"{name}.onnx", ir_version=ir_version)
    (folder / f"{name}.yaml").write_text(yaml.safe_dump(contract(**changes), sort_keys=False))
    return path


def save_with_external_data(
    graph, path: Path, *, location: str | None, attributes: bool = False
) -> Path:
    """`graph` saved with every initializer's data outside the `.onnx` file (node attributes'
    too with `attributes`): in `location` beside it, or (None) one file per tensor named after
    it, as `onnx.save_model` lays them out."""
    model = helper.make_model(graph, opset_imports=[helper.make_opsetid("", OPSET)])
    model.ir_version = IR_VERSION
    onnx.save_model(
        model,
        str(path),
        save_as_external_data=True,
        all_tensors_to_one_file=location is not None,
        location=location,
        size_threshold=0,
        convert_attribute=attributes,
    )
    return path


def onnx_external_locations(path: Path) -> set[str]:
    """The external data locations of a saved graph, as the `onnx` package lists them (the
    reference for `mjtrial.policy_files.onnx_data`)."""
    from onnx.external_data_helper import ExternalDataInfo, _get_all_tensors, uses_external_data

    model = onnx.load(str(path), load_external_data=False)
    return {ExternalDataInfo(t).location for t in _get_all_tensors(model) if uses_external_data(t)}


def doubled_above(rows: int, *, recurrent: bool = False):
    """The tanh MLP 2-8-1 whose output (with `recurrent`, its memory output `memory_out` of 3
    columns instead) has twice the batch's rows when the batch has more than `rows`: right for a
    small probe, wrong in the engine's batches."""
    graph = tanh_mlp([2, 8, 1])
    doubled = "memory_out" if recurrent else "action"
    graph.initializer.extend(
        [
            numpy_helper.from_array(np.array([0], dtype=np.int64), "first"),
            numpy_helper.from_array(np.array([1], dtype=np.int64), "one_row"),
            numpy_helper.from_array(np.array([rows], dtype=np.int64), "rows"),
        ]
    )
    if recurrent:  # memory_out: the memory fed back, as it came
        graph.node.append(helper.make_node("Identity", ["memory_in"], ["memory_kept"]))
        graph.input.append(tensor("memory_in", 3))
        graph.output.append(tensor("memory_out", 3))
        source = "memory_kept"
    else:
        for node in graph.node:
            node.output[:] = ["mlp" if o == "action" else o for o in node.output]
        source = "mlp"
    twice = helper.make_graph(
        [helper.make_node("Concat", [source, source], ["twice_out"], axis=0)],
        "twice",
        [],
        [helper.make_tensor_value_info("twice_out", TensorProto.FLOAT, None)],
    )
    once = helper.make_graph(
        [helper.make_node("Identity", [source], ["once_out"])],
        "once",
        [],
        [helper.make_tensor_value_info("once_out", TensorProto.FLOAT, None)],
    )
    graph.node.extend(
        [
            helper.make_node("Shape", ["observations"], ["shape"]),
            helper.make_node("Slice", ["shape", "first", "one_row"], ["batch"]),
            helper.make_node("Greater", ["batch", "rows"], ["more"]),
            helper.make_node("Squeeze", ["more"], ["large"]),
            helper.make_node("If", ["large"], [doubled], then_branch=twice, else_branch=once),
        ]
    )
    return graph


def shifted_above(rows: int, shift: float = 0.01):
    """The tanh MLP 2-8-1 whose action moves by `shift` when the batch has more than `rows`
    rows: invariant in small batches, batch dependent in the engine's."""
    graph = tanh_mlp([2, 8, 1])
    for node in graph.node:
        node.output[:] = ["mlp" if o == "action" else o for o in node.output]
    graph.initializer.extend(
        [
            numpy_helper.from_array(np.array([0], dtype=np.int64), "first"),
            numpy_helper.from_array(np.array([1], dtype=np.int64), "one_row"),
            numpy_helper.from_array(np.array([rows], dtype=np.int64), "rows"),
            numpy_helper.from_array(np.array(shift, dtype=np.float32), "shift"),
        ]
    )
    graph.node.extend(
        [
            helper.make_node("Shape", ["observations"], ["shape"]),
            helper.make_node("Slice", ["shape", "first", "one_row"], ["batch"]),
            helper.make_node("Greater", ["batch", "rows"], ["more"]),
            helper.make_node("Cast", ["more"], ["more_float"], to=TensorProto.FLOAT),
            helper.make_node("Mul", ["more_float", "shift"], ["offset"]),
            helper.make_node("Add", ["mlp", "offset"], ["action"]),
        ]
    )
    return graph
