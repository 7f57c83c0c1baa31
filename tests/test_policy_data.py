"""A policy graph's external data (tensors stored in files beside the `.onnx`): listed as the
`onnx` package lists them, and every such file tracked as the graph is: an input of the jobs
that run it, stamped, copied with the run (`mjtrial.policy_files.file.policy_file_paths`)."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import pytest
import yaml
from conftest import REPO_ROOT, copy_workflow, run_snakemake
from onnx import TensorProto, helper, numpy_helper
from policy_graphs import (
    contract,
    onnx_external_locations,
    save_with_external_data,
    tanh_mlp,
    write,
)

from mjtrial import provenance
from mjtrial.policy_files.file import (
    PolicyFileError,
    load_policy_file,
    policy_file_paths,
    policy_inputs,
)
from mjtrial.policy_files.onnx_data import external_data
from mjtrial.task import load_task

pytestmark = pytest.mark.end_to_end

TASK = load_task("tasks/cartpole_latency/task.py", repo_root=REPO_ROOT)


def _with_constant_and_branch():
    """The tanh MLP 2-8-1 plus a Constant node's tensor (a node attribute) and an If node whose
    branch holds its own initializer (a subgraph): tensors outside the graph's initializers."""
    graph = tanh_mlp([2, 8, 1])
    graph.output[0].name = "mlp"
    for node in graph.node:
        node.output[:] = ["mlp" if o == "action" else o for o in node.output]
    branch = helper.make_graph(
        [helper.make_node("Identity", ["branch_zero"], ["branch_out"])],
        "branch",
        [],
        [helper.make_tensor_value_info("branch_out", TensorProto.FLOAT, [1])],
        [numpy_helper.from_array(np.zeros(1, dtype=np.float32), "branch_zero")],
    )
    graph.initializer.append(numpy_helper.from_array(np.array(True), "always"))
    graph.node.extend(
        [
            helper.make_node(
                "Constant",
                [],
                ["offset"],
                value=numpy_helper.from_array(np.zeros(1, dtype=np.float32), "offset_value"),
            ),
            helper.make_node("If", ["always"], ["zero"], then_branch=branch, else_branch=branch),
            helper.make_node("Add", ["mlp", "offset"], ["shifted"]),
            helper.make_node("Add", ["shifted", "zero"], ["action"]),
        ]
    )
    graph.output[0].name = "action"
    return graph


def _policy(
    folder: Path, graph=None, *, location: str | None = "weights.bin", attributes=False
) -> Path:
    """`net.onnx` (the tanh MLP 2-8-1 unless `graph`) with its tensors' data in `location`."""
    folder.mkdir(parents=True, exist_ok=True)
    path = save_with_external_data(
        graph or tanh_mlp([2, 8, 1]), folder / "net.onnx", location=location, attributes=attributes
    )
    (folder / "net.yaml").write_text(yaml.safe_dump(contract(), sort_keys=False))
    return path


@pytest.mark.parametrize("location", ["weights.bin", None])
def test_external_data_is_listed_as_the_onnx_package_lists_it(tmp_path, location):
    path = _policy(tmp_path, _with_constant_and_branch(), location=location, attributes=True)
    listed = {t.location for t in external_data(path)}
    assert listed == onnx_external_locations(path)
    # one file for all, or one per tensor (initializers, the branch's, the Constant's)
    assert len(listed) == (1 if location else 2 * 2 + 1 + 1 + 1)
    main = [t.name for t in external_data(path) if t.main]
    assert main == ["w0", "b0", "w1", "b1", "always"]
    assert external_data(_plain(tmp_path)) == ()


def _plain(folder: Path) -> Path:
    return write(folder, "plain", tanh_mlp([2, 8, 1]))


def test_a_graphs_external_data_is_an_input_stamped_with_it(tmp_path):
    path = _policy(tmp_path)
    weights = tmp_path / "weights.bin"
    policy = load_policy_file(path, TASK)
    assert policy.files == [path, tmp_path / "net.yaml", weights]
    # what the rules name as the rollout's inputs, and what the stamps record (then copied
    # into the crate's `source/` and the zip with the graph)
    assert policy_file_paths(path) == [path, tmp_path / "net.yaml", weights]
    recorded = policy_inputs([path])["policy"]
    assert recorded == [path, tmp_path / "net.yaml", weights]
    # a graph that holds its tensors: graph and contract only, as before
    plain = _plain(tmp_path)
    assert policy_file_paths(plain) == [plain, tmp_path / "plain.yaml"]


def test_external_data_missing_or_outside_the_graphs_folder_is_one_line(tmp_path):
    path = _policy(tmp_path / "a")
    (tmp_path / "a" / "weights.bin").rename(tmp_path / "weights.bin")
    with pytest.raises(PolicyFileError) as caught:
        load_policy_file(path, TASK)
    assert str(caught.value) == (
        f"{path}: tensor 'w0' has its data in 'weights.bin', which is not a file beside it; "
        f"expected {tmp_path / 'a' / 'weights.bin'}"
    )
    (tmp_path / "a" / "weights.bin").symlink_to(tmp_path / "weights.bin")
    with pytest.raises(PolicyFileError) as caught:
        load_policy_file(path, TASK)
    assert str(caught.value) == (
        f"{path}: tensor 'w0' has its data in 'weights.bin'; expected a file in the graph's "
        "folder (a relative path without '..', not a link out of it)"
    )
    # onnxruntime reads a node attribute's or a subgraph's external data from the working
    # folder: refused
    for attributes, tensor in [(True, "offset_value"), (False, "branch_zero")]:
        path = _policy(tmp_path / "b", _with_constant_and_branch(), attributes=attributes)
        with pytest.raises(PolicyFileError) as caught:
            load_policy_file(path, TASK)
        assert str(caught.value) == (
            f"{path}: tensor {tensor!r} has its data in 'weights.bin', a node attribute's or a "
            "subgraph's, which onnxruntime looks for in the working folder; expected external "
            "data for the main graph's initializers only"
        )


def test_a_data_file_is_a_rollout_input_stamped_and_its_edit_reruns_the_condition(tmp_path):
    """The rollout of a condition whose graph keeps its weights in `weights.bin`: the stamp
    records the file, and an edit of its bytes alone (its time kept) reruns the shard."""
    workdir = copy_workflow(tmp_path)
    _policy(workdir / "policies" / "external")
    config = yaml.safe_load((REPO_ROOT / "config" / "cartpole_latency.yaml").read_text())
    config["experiment"] = "external"
    config["states"]["n"] = config["rollout"]["shard_size"] = 16
    config["conditions"]["graph"] = {"latency": 0.0, "policy": "policies/external/net.onnx"}
    for study in ("sweep", "variants"):
        config.pop(study, None)
    (workdir / "config" / "config.yaml").write_text(yaml.safe_dump(config, sort_keys=False))
    shard = "results/external/rollouts/graph/shard-00000.parquet"
    run_snakemake(workdir, shard)
    recorded = provenance.read_stamp(workdir / shard)["inputs"]["policy"]
    weights = workdir / "policies" / "external" / "weights.bin"
    assert {r["path"]: r["sha256"] for r in recorded} == {
        "policies/external/net.onnx": provenance.file_sha256(weights.with_name("net.onnx")),
        "policies/external/net.yaml": provenance.file_sha256(weights.with_name("net.yaml")),
        "policies/external/weights.bin": provenance.file_sha256(weights),
    }
    assert "Nothing to be done" in run_snakemake(workdir, shard, "-n").stdout
    edited = bytearray(weights.read_bytes())
    edited[0] ^= 1
    times = weights.stat()
    weights.write_bytes(bytes(edited))
    os.utime(weights, ns=(times.st_atime_ns, times.st_mtime_ns))
    dry = run_snakemake(workdir, shard, "-n").stdout
    assert "rollout" in dry and "Nothing to be done" not in dry


def test_a_benchmark_record_names_the_data_files_and_evaluation_sees_their_edit(tmp_path):
    """A training record of a policy file holds its data files' sha256 (`data`), and the
    evaluation refuses a record whose data file changed since, as it does the graph's."""
    from mjtrial.stages.evaluate import changed_policy_files
    from mjtrial.stages.train import policy_record

    _policy(tmp_path / "policies" / "external")
    record = {"policy": policy_record("policies/external/net.onnx", TASK, tmp_path)}
    weights = tmp_path / "policies" / "external" / "weights.bin"
    assert record["policy"]["data"] == {
        "policies/external/weights.bin": provenance.file_sha256(weights)
    }
    assert changed_policy_files(record, tmp_path) == []
    weights.write_bytes(weights.read_bytes()[::-1])
    assert changed_policy_files(record, tmp_path) == ["policies/external/weights.bin"]
    plain = _plain(tmp_path / "policies")
    assert "data" not in policy_record(plain.relative_to(tmp_path).as_posix(), TASK, tmp_path)
