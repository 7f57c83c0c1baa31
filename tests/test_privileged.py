"""The course's cheap test of a policy, in the config: a policy that reads a simulator-only
quantity (here the cart-pole's joint velocities, `qvel`, read directly) is refused, naming the
observation, unless `privileged_observations` allows it with a reason, which the manifest
then records."""

from __future__ import annotations

import copy

import pytest
import yaml
from conftest import REPO_ROOT

from mjtrial.config import ConfigError, check_config
from mjtrial.stages.manifest import task_record

SOURCE = "config/cartpole_latency.yaml"
CARTPOLE = yaml.safe_load((REPO_ROOT / SOURCE).read_text())

# A cart-pole whose LQR reads the joint velocities from the simulator's qvel.
QVEL_TASK = f'''
from dataclasses import replace

import numpy as np

from mjtrial.sim.controllers import StateFeedback, lqr_gain

import importlib.util, sys
spec = importlib.util.spec_from_file_location(
    "cartpole_task", "{REPO_ROOT / "tasks" / "cartpole_latency" / "task.py"}"
)
cartpole = importlib.util.module_from_spec(spec)
sys.modules["cartpole_task"] = cartpole
spec.loader.exec_module(cartpole)


def policy(model, params):
    per_control = cartpole._steps(params["control_period"], model)
    gain = lqr_gain(
        model, q=cartpole.STATE_COST, r=cartpole.CONTROL_COST, steps_per_control=per_control
    )
    return StateFeedback(gain, ctrl_range=model.actuator_ctrlrange)


TASK = replace(
    cartpole.TASK,
    model="{REPO_ROOT / "tasks" / "cartpole_latency" / "cartpole.xml"}",
    controller=replace(
        cartpole.TASK.controller,
        policy=policy,
        observations=("cart_position", "pole_angle", "cart_velocity", "pole_rate"),
    ),
)
'''


@pytest.fixture
def qvel_config(tmp_path):
    task_file = tmp_path / "qvel_task.py"
    task_file.write_text(QVEL_TASK)
    config = copy.deepcopy(CARTPOLE)
    config["task"] = str(task_file)
    return config


def test_a_policy_reading_qvel_is_refused_naming_the_observation(qvel_config):
    with pytest.raises(ConfigError) as err:
        check_config(qvel_config, source=SOURCE, repo_root=REPO_ROOT)
    message = str(err.value)
    assert message.startswith(f"{SOURCE}: task: {qvel_config['task']}: the policy reads ")
    assert "'cart_velocity', a privileged observation (no real-world source)" in message
    assert "\n" not in message


def test_an_allowance_with_a_reason_admits_it_and_the_manifest_records_it(qvel_config):
    allowance = {
        "cart_velocity": "the real cart has a motor encoder with velocity output",
        "pole_rate": "a gyro on the pole is planned",
    }
    qvel_config["privileged_observations"] = allowance
    check_config(qvel_config, source=SOURCE, repo_root=REPO_ROOT)
    record = task_record(qvel_config, repo_root=REPO_ROOT)
    assert record["privileged_observations"] == allowance
    assert record["observations"] == {
        "cart_position": "cart encoder",
        "pole_angle": "pole encoder",
        "cart_velocity": None,
        "pole_rate": None,
    }


def test_an_allowance_the_policy_does_not_need_is_refused(qvel_config):
    qvel_config["privileged_observations"] = {"cart_velocity": "encoder", "pole_rate": "gyro"}
    qvel_config["privileged_observations"]["pole_angle"] = "not privileged at all"
    with pytest.raises(ConfigError, match="privileged_observations.pole_angle: not a privileged"):
        check_config(qvel_config, source=SOURCE, repo_root=REPO_ROOT)
    config = copy.deepcopy(CARTPOLE)  # the built-in policy reads encoders only
    config["privileged_observations"] = {"pole_rate": "gyro"}
    with pytest.raises(ConfigError, match="the policy reads no privileged observation"):
        check_config(config, source=SOURCE, repo_root=REPO_ROOT)


def test_the_built_in_tasks_read_no_privileged_observation():
    for source in (SOURCE, "config/config.yaml"):
        config = yaml.safe_load((REPO_ROOT / source).read_text())
        record = task_record(config, repo_root=REPO_ROOT)
        assert None not in record["observations"].values()
        assert record["privileged_observations"] == {}
