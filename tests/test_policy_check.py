"""`mjtrial policy check` and the config's check of a policy file against graphs that change
with the batch: a shape that is right for a small probe and wrong in the engine's batches is one
line naming the file and the output; a value that changes only in large batches is found by the
invariance check at the engine's batch size."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import yaml
from conftest import REPO_ROOT, copy_workflow
from policy_graphs import doubled_above, shifted_above, tanh_mlp, write

from mjtrial.cli import main
from mjtrial.config import ConfigError, check_config
from mjtrial.policy_files import file as policy_file
from mjtrial.policy_files.file import PolicyFileError, load_policy_file
from mjtrial.task import BoundTask, load_task

TASK_FILE = str(REPO_ROOT / "tasks" / "cartpole_latency" / "task.py")
TASK = load_task(TASK_FILE, repo_root=REPO_ROOT)
MEMORY = [{"input": "memory_in", "output": "memory_out", "size": 3}]


def _doubled(folder: Path, rows: int, *, recurrent: bool) -> Path:
    if recurrent:
        return write(folder, "memory", doubled_above(rows, recurrent=True), recurrent=MEMORY)
    return write(folder, "action", doubled_above(rows))


@pytest.mark.parametrize(
    ("recurrent", "output", "width"), [(False, "action", 1), (True, "memory_out", 3)]
)
def test_an_output_with_twice_the_rows_above_the_probe_is_one_line(
    tmp_path, capsys, recurrent, output, width
):
    """Right for 2 rows, twice the rows above: the probe at the engine's largest batch says so
    (before, a traceback; a memory that doubles at each call grew until the process died)."""
    path = _doubled(tmp_path, 2, recurrent=recurrent)
    assert main(["policy", "check", str(path), "--task", TASK_FILE]) == 2
    assert capsys.readouterr().err == (
        f"mjtrial policy check: {path}: output {output!r} of a batch of 256 rows has shape "
        f"(512, {width}) and dtype float32; expected (256, {width}) float32 ("
        + (
            "the recurrent state's size"
            if recurrent
            else "one per actuator entry of the contract, 3 per mocap body"
        )
        + ")\n"
    )


@pytest.mark.parametrize(
    ("recurrent", "output", "width"), [(False, "action", 1), (True, "memory_out", 3)]
)
def test_an_output_whose_rows_change_between_probes_is_one_line_at_the_call(
    tmp_path, monkeypatch, recurrent, output, width
):
    """A shape right at the probes' sizes and wrong between them: every call checks its
    answer (a memory that doubles would otherwise grow at each call)."""
    path = _doubled(tmp_path, 2, recurrent=recurrent)
    monkeypatch.setattr(policy_file, "PROBE_ROWS", (2,))  # as if the probes had missed it
    checked = load_policy_file(path, TASK)
    batch = checked.policy(BoundTask.of(TASK).model, TASK.parameters({}))
    batch.reset(8)
    with pytest.raises(PolicyFileError) as caught:
        batch(np.zeros((8, 2)))
    assert str(caught.value) == (
        f"{path}: output {output!r} of a batch of 8 rows has shape (16, {width}); expected "
        f"(8, {width}), one row per episode"
    )


@pytest.mark.parametrize(
    ("recurrent", "output", "width"), [(False, "action", 1), (True, "memory_out", 3)]
)
def test_an_output_of_two_rows_for_one_is_one_line_in_the_replay_of_an_episode_alone(
    tmp_path, monkeypatch, recurrent, output, width
):
    """The replay's path (`OnnxPolicy.alone`, its outputs bound to arrays of one row) says what
    the checked call says of a graph that answers one row with two: no onnxruntime error."""
    path = _doubled(tmp_path, 0, recurrent=recurrent)
    monkeypatch.setattr(policy_file, "PROBE_ROWS", ())  # as if the probes had missed it
    policy = load_policy_file(path, TASK).policy(BoundTask.of(TASK).model, TASK.parameters({}))
    with pytest.raises(PolicyFileError) as caught:
        policy.alone(np.zeros((3, 2)))
    assert str(caught.value) == (
        f"{path}: output {output!r} of a batch of 1 rows has shape (2, {width}); expected "
        f"(1, {width}), one row per episode"
    )


def test_the_config_check_names_the_condition_and_the_graph(tmp_path):
    workdir = copy_workflow(tmp_path)
    _doubled(workdir / "policies" / "bad", 2, recurrent=True)
    config = yaml.safe_load((REPO_ROOT / "config" / "cartpole_latency.yaml").read_text())
    config["conditions"]["graph"] = {"latency": 0.0, "policy": "policies/bad/memory.onnx"}
    with pytest.raises(ConfigError) as caught:
        check_config(config, source="config/config.yaml", repo_root=workdir)
    assert str(caught.value) == (
        "config/config.yaml: conditions.graph.policy: policies/bad/memory.onnx: output "
        "'memory_out' of a batch of 256 rows has shape (512, 3) and dtype float32; expected "
        "(256, 3) float32 (the recurrent state's size)"
    )


def test_invariance_is_checked_at_the_engines_batch_size(tmp_path, capsys):
    """A graph whose action moves only in batches of more than 16 rows: invariant in the 8
    rows checked before, not in the engine's 131, whose replays refuse it, named as a batch
    dependence."""
    path = write(tmp_path, "shifted", shifted_above(16))
    assert main(["policy", "check", str(path), "--task", TASK_FILE]) == 2
    assert capsys.readouterr().err == (
        f"mjtrial policy check: {path.with_suffix('.yaml')}: policy: batch dependence: episode "
        "row 0 of a batch of 131 gets other controls at control instant 0 when it runs alone "
        "(largest difference 0.15): its results would depend on the batch (rollout.shard_size); "
        "compute each row from that row's observations alone\n"
    )
    invariant = write(tmp_path, "plain", tanh_mlp([2, 8, 1]))
    assert main(["policy", "check", str(invariant), "--task", TASK_FILE]) == 0
    assert (
        "  batch invariance: 131 episodes alone and in one batch (the engine's) agree bit for bit"
        in capsys.readouterr().out.splitlines()
    )
