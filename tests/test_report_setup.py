"""The report's setup says what is true of each condition: the output columns of the policy
each condition runs (a policy file's own contract, not the task's scripted order), the
policy's rate."""

from __future__ import annotations

import mujoco
from fetch_mocap import FETCH, FINGERS, fetch_task
from policy_graphs import tanh_mlp, write

from mjtrial.report.setup import _controller_lines

MOCAP = {"body": "robot0:mocap", "relative_to": "target", "scale": 0.01}


def test_each_condition_is_said_with_its_own_policys_columns(tmp_path):
    """The task's scripted policy puts the mocap first (columns 0-2) and the fingers last
    (column 3); a behaviour clone's contract puts a signed gripper column first."""
    write(
        tmp_path / "policies",
        "clone",
        tanh_mlp([2, 8, 4]),
        task="fetch_mocap",
        observations=["object_x", "object_y"],
        actuators=[{"actuators": list(FINGERS), "signs": [1, -1]}],
        mocap=[MOCAP],
        control_period=0.04,
    )
    model = mujoco.MjModel.from_xml_path(str(FETCH))
    conditions = {"scripted": {}, "clone": {"policy": "policies/clone.onnx"}, "again": {}}
    lines = _controller_lines(model, fetch_task(), conditions, tmp_path)
    text = "\n".join(lines)
    scripted = text.index("- The policy's output columns under `scripted`, `again`, in order:")
    clone = text.index(
        "- The policy's output columns under `clone`, in order (its contract "
        "`policies/clone.yaml`: a column in [-1, 1] mapped onto its actuators' ctrlrange, "
        "then clipped):"
    )
    scripted_part = text[scripted:clone] if scripted < clone else text[scripted:]
    clone_part = text[clone:scripted] if clone < scripted else text[clone:]
    assert "  - columns 0-2: the target position of mocap body `robot0:mocap`" in scripted_part
    assert (
        f"  - column 3: the ctrl of `{FINGERS[0]}`, `{FINGERS[1]}` = its joint's" in scripted_part
    )
    assert (
        f"  - column 0: the ctrl of `{FINGERS[0]}` = 1 × the value; the ctrl of `{FINGERS[1]}` "
        "= −1 × the value" in clone_part
    )
    assert (
        "  - columns 1-3: the target position of mocap body `robot0:mocap` = the previous "
        "target + 0.01 × the values" in clone_part
    )
    # one mapping for every condition: no names
    alone = "\n".join(_controller_lines(model, fetch_task(), {"a": {}, "b": {}}, tmp_path))
    assert "- The policy's output columns, in order:" in alone


def test_the_initial_states_say_each_parameters_distribution():
    from gantry_lift.task import TASK

    from mjtrial.report.setup import _initial_states_lines

    states = {
        "n": 10,
        "seed": 3,
        "ranges": {"dx": [-0.02, 0.02], "dy": [-0.01, 0.01], "yaw": [-0.6, 0.6], "mass": [0.05, 1]},
    }
    uniform = "\n".join(_initial_states_lines(states, TASK, "PCG64"))
    assert "one uniform draw of n values per parameter in the order dx, dy, yaw, mass:" in uniform
    assert "| mass | 0.05 | 1 | kg |" in uniform
    states["distributions"] = {
        "dx": {"kind": "normal", "mean": 0, "std": 0.005},
        "mass": {"kind": "truncated_normal", "mean": 0.3, "std": 0.1},
    }
    text = "\n".join(_initial_states_lines(states, TASK, "PCG64"))
    assert "| dx | normal, mean 0, std 0.005 (not truncated) | m |" in text
    assert "| dy | uniform in [-0.01, 0.01] | m |" in text
    assert "| mass | normal, mean 0.3, std 0.1, truncated to [0.05, 1] | kg |" in text


def test_the_rates_are_the_physics_and_the_policys_under_each_condition():
    """The cart-pole as its design record says: a 2 ms timestep, a 10 ms control period, 0 and
    20 ms of sensing latency; the gantry's controls are open loop."""
    import yaml
    from conftest import REPO_ROOT

    from mjtrial.report.setup import _rate_lines
    from mjtrial.sim.physics import load_model
    from mjtrial.task import load_task

    config = yaml.safe_load((REPO_ROOT / "config" / "cartpole_latency.yaml").read_text())
    task = load_task(config["task"], repo_root=REPO_ROOT)
    model_file = REPO_ROOT / config["model"]
    lines = _rate_lines(load_model(model_file), task, config, model_file)
    held = "between two actions the controls they set are held at every physics step."
    assert lines == [
        "- Rates under `no_latency`: the physics steps every 2 ms, 500 Hz; the policy acts "
        f"every 5 physics steps (10 ms, 100 Hz); {held}",
        "- Rates under `latency_20ms`: the physics steps every 2 ms, 500 Hz; the policy acts "
        f"every 5 physics steps (10 ms, 100 Hz) on observations 10 physics steps (20 ms) old; "
        f"{held}",
    ]
    gantry = yaml.safe_load((REPO_ROOT / "config" / "config.yaml").read_text())
    model_file = REPO_ROOT / gantry["model"]
    open_loop = _rate_lines(
        load_model(model_file), load_task(gantry["task"], repo_root=REPO_ROOT), gantry, model_file
    )
    assert len(open_loop) == 1 and "the controls are an open-loop sequence" in open_loop[0]


def test_policy_check_says_a_signed_columns_signs():
    from mjtrial.policy_files.check import _actuator

    assert _actuator(("left", "right"), (1, -1)) == "[+left, -right]"
    assert _actuator(("left", "right")) == "[left, right]"
    assert _actuator("cart_motor") == "cart_motor"
