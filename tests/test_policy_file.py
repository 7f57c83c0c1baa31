"""Policy files: an ONNX graph with its contract, checked against the task and the graph before any
rollout (each mismatch one line naming the file), run by onnxruntime in the closed-loop engine
with the project's guarantee (an episode's outcome independent of its batch and threads, two
runs bit for bit), a non-finite action a failure category, and a condition that names a file.

The independent reference: a graph that computes the cart-pole's encoder LQR (finite-difference
velocities from a recurrent state) must give the LQR condition's outcomes.
"""

from __future__ import annotations

import hashlib
import json
from pathlib import Path

import numpy as np
import pyarrow.parquet as pq
import pytest
import yaml
from conftest import REPO_ROOT, copy_workflow, run_snakemake
from onnx import TensorProto
from policy_graphs import encoder_lqr, sqrt_of_angle, tanh_mlp, write

from mjtrial import provenance
from mjtrial.config import ConfigError, check_config
from mjtrial.policy_files.file import PolicyFileError, load_policy_file, policy_task
from mjtrial.replay import replay_episode
from mjtrial.sim.engine import iter_batches
from mjtrial.task import NONFINITE_ACTION, BoundTask, load_task

pytestmark = pytest.mark.end_to_end

TASK = load_task("tasks/cartpole_latency/task.py", repo_root=REPO_ROOT)
PERIOD = 0.01  # s, the cart-pole's control period
FALL = {"fall_angle": 0.5}
RECURRENT = [{"input": "memory_in", "output": "memory_out", "size": 3}]


def _gain() -> np.ndarray:
    import importlib

    return importlib.import_module(TASK.controller.policy.__module__).design_gain(PERIOD)


def _lqr_file(folder: Path) -> Path:
    return write(
        folder, "encoder-lqr", encoder_lqr(_gain(), PERIOD), action_scale="raw", recurrent=RECURRENT
    )


def _states(n: int, seed: int = 1) -> dict[str, np.ndarray]:
    rng = np.random.default_rng(seed)
    return {p.name: rng.uniform(p.low, p.high, n) for p in TASK.state_parameters}


def _run(task, values, *, batch_size=16, nthread=0, condition=None):
    batches = list(
        iter_batches(
            BoundTask.of(task),
            values,
            condition or {"latency": 0.0},
            thresholds=FALL,
            batch_size=batch_size,
            nthread=nthread,
        )
    )
    return {
        "physics": np.concatenate([b.episodes.physics for b in batches]),
        "ctrl": np.concatenate([b.episodes.ctrl for b in batches]),
        **{k: np.concatenate([b.outcome[k] for b in batches]) for k in batches[0].outcome},
    }


@pytest.mark.parametrize(
    ("graph", "changes", "named", "message"),
    [
        (
            tanh_mlp([2, 8, 1]),
            {"observations": ["cart_position", "cart_speed"]},
            "yaml",
            "observations: 'cart_speed' is not an observation of task 'cartpole_latency'",
        ),
        (tanh_mlp([2, 8, 2]), {}, "onnx", "graph output 'action' has 2 columns; expected 1"),
        (tanh_mlp([2, 8, 1], batch=1), {}, "onnx", "has a fixed batch dimension 1"),
        (
            tanh_mlp([2, 8, 1]),
            {"ir_version": 14},
            "onnx",
            "IR version 14, newer than onnxruntime 1.31.1 reads (at most 13)",
        ),
        (
            tanh_mlp([2, 8, 1], dtype=TensorProto.DOUBLE),
            {},
            "onnx",
            "graph input 'observations' is tensor(double); expected float32",
        ),
        (
            tanh_mlp([2, 8, 1]),
            {"input": "obs"},
            "yaml",
            "input 'obs' is not an input of",
        ),
        (tanh_mlp([3, 8, 1]), {}, "onnx", "has 3 columns; expected 2"),
        (tanh_mlp([2, 8, 1]), {"task": "reacher_goal"}, "yaml", "expected 'cartpole_latency'"),
        (tanh_mlp([2, 8, 1]), {"actuator": ["cart_motor"]}, "yaml", "(top level): Additional"),
        (
            tanh_mlp([2, 8, 1]),
            {"normalization": {"mean": [0.0], "std": [1.0]}},
            "yaml",
            "normalization.mean: 1 numbers; expected 2",
        ),
    ],
)
def test_a_bad_contract_or_graph_is_one_line_naming_the_file(
    tmp_path, graph, changes, named, message
):
    path = write(tmp_path, "net", graph, **changes)
    with pytest.raises(PolicyFileError) as caught:
        load_policy_file(path, TASK)
    text = str(caught.value)
    assert "\n" not in text and message in text, text
    assert text.startswith(str(path.with_suffix(f".{named}"))), text


def test_a_folder_contract_serves_every_file_and_a_missing_one_is_named(tmp_path):
    path = write(tmp_path, "seed-0", tanh_mlp([2, 8, 1]))
    path.with_suffix(".yaml").rename(tmp_path / "policy.yaml")
    assert load_policy_file(path, TASK).contract.source == tmp_path / "policy.yaml"
    (tmp_path / "policy.yaml").unlink()
    with pytest.raises(PolicyFileError, match=r"seed-0.onnx: no contract; expected seed-0.yaml"):
        load_policy_file(path, TASK)


def test_a_control_period_other_than_the_tasks_is_refused(tmp_path):
    policy = load_policy_file(
        write(tmp_path, "net", tanh_mlp([2, 8, 1]), control_period=0.02), TASK
    )
    with pytest.raises(PolicyFileError) as caught:
        policy.policy(BoundTask.of(TASK).model, TASK.parameters({}))
    assert str(caught.value) == (
        f"{tmp_path / 'net.yaml'}: control_period 0.02 s; expected the task's, 0.01 s, under "
        "this condition"
    )


@pytest.mark.parametrize("sizes", [[2, 64, 64, 1], [2, 256, 256, 1], [2, 512, 512, 512, 1]])
def test_rows_do_not_depend_on_the_batch_and_two_sessions_agree(tmp_path, sizes):
    """The settings chosen (`SESSION_SETTINGS`) hold on tanh MLPs from small to large: every row
    has the same bits alone, in any slice, and from a second session."""
    path = write(tmp_path, "net", tanh_mlp(sizes, seed=len(sizes)))
    model, params = BoundTask.of(TASK).model, TASK.parameters({})
    first = load_policy_file(path, TASK).policy(model, params)
    second = load_policy_file(path, TASK).policy(model, params)
    rows = np.random.default_rng(0).normal(size=(200, 2))
    first.reset(200)
    together = first(rows)
    second.reset(200)
    np.testing.assert_array_equal(second(rows), together)
    rng = np.random.default_rng(1)
    for size in [1, 2, 3, 7, 16, 63, 100, 199, *rng.integers(1, 200, 4)]:
        start = int(rng.integers(0, 200 - size + 1))
        first.reset(size)
        np.testing.assert_array_equal(first(rows[start : start + size]), together[start:][:size])


def test_the_lqr_as_a_graph_gives_the_lqr_conditions_outcomes(tmp_path):
    """An independent reference: the task's LQR (float64) against the same law in a float32
    graph with a recurrent state: the same successes, peak angles within float32 rounding."""
    graph = policy_task(TASK, load_policy_file(_lqr_file(tmp_path), TASK))
    values = _states(32)
    for latency in (0.0, 0.02):
        lqr = _run(TASK, values, condition={"latency": latency})
        onnx = _run(graph, values, condition={"latency": latency})
        assert 0 < lqr["success"].sum() < 32
        np.testing.assert_array_equal(onnx["success"], lqr["success"])
        np.testing.assert_allclose(onnx["peak_angle"], lqr["peak_angle"], rtol=1e-5)
        np.testing.assert_allclose(onnx["ctrl"], lqr["ctrl"], atol=1e-2)


def test_outcomes_do_not_depend_on_batch_size_or_threads_and_runs_agree(tmp_path):
    graph = policy_task(TASK, load_policy_file(_lqr_file(tmp_path), TASK))
    values = _states(20, seed=2)
    reference = _run(graph, values, batch_size=16)
    for batch_size, nthread in [(16, 0), (5, 2), (1, 0)]:
        again = _run(graph, values, batch_size=batch_size, nthread=nthread)
        np.testing.assert_array_equal(again["physics"], reference["physics"])
        np.testing.assert_array_equal(again["ctrl"], reference["ctrl"])


def test_a_non_finite_action_is_a_failure_category_not_a_crash(tmp_path):
    """ctrl 0 while the pole angle is >= 0, NaN once negative: an episode starting tilted back
    fails at its first instant, gets no control from then on, and is classified so."""
    graph = policy_task(TASK, load_policy_file(write(tmp_path, "nan", sqrt_of_angle()), TASK))
    values = _states(12, seed=3)
    out = _run(graph, values, batch_size=5)
    back = values["pole_angle"] < 0
    assert back.any() and (~back).any()
    assert (out["failure_category"][back] == NONFINITE_ACTION).all()
    assert not out["success"][back].any()
    assert (out["ctrl"][back] == 0).all()
    np.testing.assert_array_equal(_run(graph, values, batch_size=1)["physics"], out["physics"])


def _per_call(policy, observations: np.ndarray) -> np.ndarray:
    """What a reset and one call per instant give one episode: (k, nu)."""
    policy.reset(1)
    return np.concatenate([policy(observations[k : k + 1]) for k in range(len(observations))])


@pytest.mark.parametrize(
    "case", ["recurrent, raw", "normalized, ctrlrange", "non-finite from instant 5"]
)
def test_one_episode_alone_is_a_reset_and_a_call_per_instant_bit_for_bit(tmp_path, case):
    """`OnnxPolicy.alone`, the replay check's path for a policy file, against the plain per-call
    path (what the reference episode and verify's re-simulation run): the same bits, for a
    recurrent state with clipped actions, a normalization with a scaled action, and an action
    that turns non-finite partway (ctrl 0 from then on, even where it is finite again)."""
    rng = np.random.default_rng(7)
    observations = rng.normal(scale=0.3, size=(40, 2))
    if case == "recurrent, raw":
        path = _lqr_file(tmp_path)
    elif case == "normalized, ctrlrange":
        normalization = {"mean": [0.1, -0.05], "std": [0.4, 0.2]}
        path = write(tmp_path, "mlp", tanh_mlp([2, 16, 1], seed=3), normalization=normalization)
        observations *= 5
    else:
        path = write(tmp_path, "nan", sqrt_of_angle())
        observations[:, 1] = np.abs(observations[:, 1])
        observations[5, 1] = -0.1  # NaN at instant 5 only
    model, params = BoundTask.of(TASK).model, TASK.parameters({})
    policy = load_policy_file(path, TASK).policy(model, params)
    expected = _per_call(policy, observations)
    got = policy.alone(observations)
    np.testing.assert_array_equal(got, expected)
    if case == "non-finite from instant 5":
        assert (got[5:] == 0).all()
    elif case == "recurrent, raw":
        low, high = model.actuator_ctrlrange[0]
        assert got.min() == low and got.max() == high  # actions clipped at both ends
    else:
        assert np.isfinite(got).all() and len(np.unique(got)) == len(got)


# --------------------------------------------------------------------------------------------
# A condition that names a policy file
# --------------------------------------------------------------------------------------------

GRAPH = "policies/encoder_lqr/encoder-lqr.onnx"


def _config(policy: str = GRAPH) -> dict:
    config = yaml.safe_load((REPO_ROOT / "config" / "cartpole_latency.yaml").read_text())
    config["experiment"] = "graph_vs_lqr"
    config["states"]["n"] = 16
    config["rollout"]["shard_size"] = 16
    config["analysis"]["n_resamples"] = 300
    config["conditions"] = {
        "lqr": {"latency": 0.0},
        "graph": {"latency": 0.02, "policy": policy},
    }
    config["design"]["falsifier"].update(treatment="lqr", baseline="graph")
    config.pop("sweep", None)
    config.pop("variants", None)
    return config


@pytest.fixture(scope="module")
def workdir(tmp_path_factory) -> Path:
    workdir = copy_workflow(tmp_path_factory.mktemp("graph"))
    _lqr_file(workdir / Path(GRAPH).parent)
    (workdir / "config" / "config.yaml").write_text(yaml.safe_dump(_config(), sort_keys=False))
    return workdir


def _check(workdir: Path, config: dict) -> str:
    with pytest.raises(ConfigError) as caught:
        check_config(config, source="config/config.yaml", repo_root=workdir)
    assert "\n" not in str(caught.value)
    return str(caught.value)


def test_a_conditions_policy_file_is_checked_with_the_config(workdir):
    check_config(_config(), source="config/config.yaml", repo_root=workdir)
    folder = workdir / "policies" / "bad"
    write(folder, "period", tanh_mlp([2, 8, 1]), control_period=0.02)
    assert _check(workdir, _config("policies/bad/period.onnx")) == (
        "config/config.yaml: conditions.graph.policy: policies/bad/period.yaml: control_period "
        "0.02 s; expected the task's, 0.01 s, under this condition"
    )
    write(folder, "fixed", tanh_mlp([2, 8, 1], batch=4))
    assert _check(workdir, _config("policies/bad/fixed.onnx")).startswith(
        "config/config.yaml: conditions.graph.policy: policies/bad/fixed.onnx: graph input "
        "'observations' has a fixed batch dimension 4"
    )
    assert "conditions.graph.policy: policies/bad/none.onnx: expected an existing .onnx" in (
        _check(workdir, _config("policies/bad/none.onnx"))
    )


def test_a_privileged_input_is_refused_unless_the_config_allows_it(workdir):
    write(
        workdir / "policies" / "bad",
        "rates",
        tanh_mlp([3, 8, 1]),
        observations=["cart_position", "pole_angle", "pole_rate"],
    )
    config = _config("policies/bad/rates.onnx")
    assert _check(workdir, config).startswith(
        "config/config.yaml: conditions.graph.policy: policies/bad/rates.yaml: the policy reads "
        "'pole_rate', a privileged observation"
    )
    config["privileged_observations"] = {"pole_rate": "an upper bound: the rate measured"}
    check_config(config, source="config/config.yaml", repo_root=workdir)


@pytest.fixture(scope="module")
def run(workdir) -> Path:
    run_snakemake(workdir)
    return workdir / "results" / "graph_vs_lqr"


def test_a_policy_file_condition_runs_end_to_end_as_the_lqr_would(run, workdir):
    lqr = pq.read_table(run / "rollouts" / "lqr.parquet").to_pydict()
    graph_table = pq.read_table(run / "rollouts" / "graph.parquet")
    # the graph under 20 ms against the task's own LQR under 20 ms, in this process
    reference = _run(TASK, _states_of(run), condition={"latency": 0.02})
    graph = graph_table.to_pydict()
    assert graph["success"] == reference["success"].tolist()
    assert len(lqr["success"]) == 16
    stamp = provenance.read_stamp(run / "rollouts" / "graph.parquet")
    recorded = {Path(r["path"]).name: r["sha256"] for r in stamp["inputs"]["policy"]}
    onnx_file = workdir / GRAPH
    assert recorded == {
        onnx_file.name: hashlib.sha256(onnx_file.read_bytes()).hexdigest(),
        "encoder-lqr.yaml": hashlib.sha256(onnx_file.with_suffix(".yaml").read_bytes()).hexdigest(),
    }
    runtime = stamp["extra"]["policy_runtime"]
    assert runtime["onnxruntime"] == "1.31.1" and runtime["intra_op_num_threads"] == 1
    assert "policy_runtime" not in provenance.read_stamp(run / "rollouts" / "lqr.parquet")["extra"]
    summary = json.loads((run / "analysis" / "summary.json").read_text())
    assert summary["conditions"]["graph"]["policy"] == GRAPH
    # replay re-simulates a policy file's episode as recorded, and its stamp names the file
    row = next(r for r in graph_table.to_pylist() if not r["success"])
    out = workdir / "replayed.rrd"
    replay = replay_episode(
        condition="graph", state_id=row["state_id"], output=out, repo_root=workdir
    )
    assert replay.outcome["failure_category"] == row["failure_category"]
    assert replay.outcome["peak_angle"] == row["peak_angle"]
    assert provenance.read_stamp(out)["inputs"]["policy"] == stamp["inputs"]["policy"]


def _states_of(run: Path) -> dict[str, np.ndarray]:
    table = pq.read_table(run / "states.parquet")
    return {p.name: table.column(p.name).to_numpy() for p in TASK.state_parameters}


def test_a_policy_file_run_verifies_and_an_edited_contract_is_named(
    run, workdir, capsys, monkeypatch
):
    """`mjtrial verify` from the run's folder, in this process (its `main`): as built, with its
    episodes re-simulated through the graph; then with its contract edited, which its stamps
    name (no episode re-simulated: that check is the first call's)."""
    from mjtrial.cli import main

    monkeypatch.chdir(workdir)

    def verify(*args: str) -> tuple[int, str]:
        code = main(["verify", "results/graph_vs_lqr", *args])
        out = capsys.readouterr()
        return code, out.out + out.err

    code, out = verify()
    assert code == 0, out
    contract = workdir / Path(GRAPH).with_suffix(".yaml")
    contract.write_text(contract.read_text().replace("tests/policy_graphs.py", "edited"))
    code, out = verify("--resimulate", "0")
    assert code != 0
    assert "encoder-lqr.yaml" in out


def test_policy_check_reports_the_contract_a_nominal_episode_invariance_and_time(tmp_path, capsys):
    """The check on the cart-pole's own batch (131 episodes, each again alone): the slowest
    test here, kept so, since the batch the check compares at is the engine's (a graph that
    depends on the batch only in large batches shows there); the test below splits a small
    batch."""
    from mjtrial.cli import main

    task = str(REPO_ROOT / "tasks" / "cartpole_latency" / "task.py")
    assert main(["policy", "check", str(_lqr_file(tmp_path)), "--task", task]) == 0
    out = capsys.readouterr().out.splitlines()
    assert out[0].startswith(f"{tmp_path / 'encoder-lqr.onnx'}: contract ")
    assert "  nominal episode: success" in out  # the task's own LQR balances the nominal state
    # the engine's batch for the cart-pole: 131 episodes of 1,500 steps in 24 MB
    assert (
        "  batch invariance: 131 episodes alone and in one batch (the engine's) agree bit for bit"
        in out
    )
    assert out[5].startswith("  per call (median of 200): 1 row(s) ")
    bad = write(tmp_path, "bad", tanh_mlp([2, 8, 1]), observations=["pole_rate", "pole_angle"])
    assert main(["policy", "check", str(bad), "--task", task]) == 0
    assert "  privileged observations: pole_rate (a config must allow each" in (
        capsys.readouterr().out
    )
    period = ["--set", "control_period=0.02"]
    assert main(["policy", "check", str(bad), "--task", task, *period]) == 2
    err = capsys.readouterr().err
    assert err == (
        f"mjtrial policy check: {tmp_path / 'bad.yaml'}: control_period 0.01 s; expected the "
        "task's, 0.02 s, under this condition\n"
    )


def test_policy_check_compares_every_batch_the_engine_splits_the_episodes_into(
    tmp_path, capsys, monkeypatch
):
    """The cart-pole's pole mass edits the model, so the engine holds a model copy per batch
    slot; a budget of 5 copies splits the engine's batch into batches of 5 and the rest, and
    the invariant LQR graph still agrees with each episode run alone. The engine's batch here
    holds 11 episodes (its memory budget made so; the cart-pole's own 131 are the test above):
    2 batches of 5 and one of 1, 22 episodes run instead of 262."""
    import mujoco

    from mjtrial.cli import main
    from mjtrial.sim import engine

    bound = BoundTask.of(TASK)
    size = mujoco.mj_sizeModel(bound.model)
    episode = engine.episode_bytes(bound.model, engine.episode_steps(bound, {}))
    monkeypatch.setattr(engine, "BATCH_BYTES", 11 * episode)
    monkeypatch.setattr(engine, "MODEL_COPIES_BYTES", 5 * size + size // 2)
    task = str(REPO_ROOT / "tasks" / "cartpole_latency" / "task.py")
    assert main(["policy", "check", str(_lqr_file(tmp_path)), "--task", task]) == 0
    out = capsys.readouterr().out.splitlines()
    assert (
        "  batch invariance: 11 episodes alone and in the engine's 3 batches (2 of 5, 1 of 1) "
        "agree bit for bit" in out
    )
