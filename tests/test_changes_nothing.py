"""An edit or a state parameter that changes nothing is refused, where "nothing" is the
simulation, not the model's bytes (issue 34, item 6); a condition's edits that undo a
variant's are refused at the config check (item 7).

The reference for "the same simulation" is a plain `mj_step` loop from the reset: equal
trajectories bit for bit where `physics.simulated_sha256` says equal, different where it says
different, on the third-party Fetch model (a free object) and the built-in tasks."""

from __future__ import annotations

import copy
from dataclasses import replace

import mujoco
import numpy as np
import pytest
import yaml
from conftest import REPO_ROOT

from mjtrial.config import ConfigError, check_config
from mjtrial.sim.engine import iter_batches
from mjtrial.sim.physics import FULLPHYSICS, simulated_sha256
from mjtrial.task import (
    BoundTask,
    ModelValue,
    Rotation,
    StateParameter,
    TaskError,
    load_task,
)
from mjtrial.task.checks import run_task_code

FETCH = REPO_ROOT / "tasks" / "fetch_pick" / "assets" / "fetch" / "pick_and_place.xml"
OBJECT = "object0"  # Fetch's free object (joint `object0:joint`)


def _hash_and_trajectory(model: mujoco.MjModel, steps: int = 200):
    """The model's hash from its reset state, and qpos, qvel after each of `steps` mj_step."""
    data = mujoco.MjData(model)
    mujoco.mj_resetData(model, data)
    state = np.empty(mujoco.mj_stateSize(model, FULLPHYSICS))
    mujoco.mj_getState(model, data, state, FULLPHYSICS)
    trajectory = []
    for _ in range(steps):
        mujoco.mj_step(model, data)
        trajectory.append(np.concatenate([data.qpos, data.qvel]))
    return simulated_sha256(model, state), np.array(trajectory)


FETCH_EDITS = {
    # colour, and a free body's pose, which MuJoCo never reads (its qpos places it)
    "object colour": (lambda m: m.geom_rgba.__setitem__(m.geom(OBJECT).id, [1, 0, 0, 1]), True),
    "free body pos": (lambda m: m.body_pos.__setitem__((m.body(OBJECT).id, 0), 1.7), True),
    "free body quat": (lambda m: m.body_quat.__setitem__(m.body(OBJECT).id, [0, 0, 0, 1]), True),
    # below every geom it can touch (all at 1 0.005 0.0001): MuJoCo takes the larger of two
    "object friction halved": (
        lambda m: m.geom_friction.__setitem__(m.geom(OBJECT).id, [0.5, 0.005, 0.0001]),
        True,
    ),
    "object friction doubled": (
        lambda m: m.geom_friction.__setitem__(m.geom(OBJECT).id, [2.0, 0.005, 0.0001]),
        False,
    ),
    "object mass": (lambda m: m.body_mass.__setitem__(m.body(OBJECT).id, 5.0), False),
    "a joint's damping": (lambda m: m.dof_damping.__setitem__(0, 3.0), False),
    "timestep": (lambda m: setattr(m.opt, "timestep", 0.001), False),
}


@pytest.mark.parametrize("edit", FETCH_EDITS, ids=list(FETCH_EDITS))
def test_equal_hashes_are_equal_simulations_on_fetch(edit):
    nominal = mujoco.MjModel.from_xml_path(str(FETCH))
    change, same = FETCH_EDITS[edit]
    edited = copy.copy(nominal)
    change(edited)
    mujoco.mj_setConst(edited, mujoco.MjData(edited))
    (h0, t0), (h1, t1) = _hash_and_trajectory(nominal), _hash_and_trajectory(edited)
    assert np.array_equal(t0, t1) == same  # the reference: a plain step loop
    assert (h0 == h1) == same


@pytest.mark.parametrize(
    ("apply", "message"),
    [
        (
            Rotation("body", OBJECT, 2),
            "body 'object0' is placed by its free joint 'object0:joint', so MuJoCo ignores its "
            "body quat (no episode would differ); expected a Custom applier (stage 'initial') "
            "that turns joint 'object0:joint''s quaternion (qpos[3:7], w-x-y-z) in the initial "
            "state",
        ),
        (
            ModelValue("body", OBJECT, "pos", 0),
            "body 'object0' is placed by its free joint 'object0:joint', so MuJoCo ignores its "
            "body pos (no episode would differ); expected a JointPosition on joint "
            "'object0:joint' (index 0, 1, 2: x, y, z)",
        ),
    ],
)
def test_a_free_bodys_pose_in_the_model_is_refused_naming_the_body(apply, message):
    with pytest.raises(TaskError) as err:
        apply.bind(mujoco.MjModel.from_xml_path(str(FETCH)))
    assert str(err.value) == message


def test_the_gantry_cubes_yaw_by_rotation_is_one_line_naming_the_parameter():
    gantry = load_task("tasks/gantry_lift/task.py", repo_root=REPO_ROOT)
    yaw = StateParameter("cube_yaw", "rad", -0.5, 0.5, Rotation("body", "cube", 2))
    with pytest.raises(TaskError) as err:
        BoundTask.of(replace(gantry, state_parameters=(*gantry.state_parameters, yaw)))
    assert "state parameter 'cube_yaw': body 'cube' is placed by its free joint" in str(err.value)
    assert "\n" not in str(err.value)


def test_a_state_parameter_that_only_colours_a_geom_is_refused():
    cartpole = load_task("tasks/cartpole_latency/task.py", repo_root=REPO_ROOT)
    shade = StateParameter("shade", "1", 0.1, 0.9, ModelValue("geom", "cart", "rgba", 0))
    bound = BoundTask.of(replace(cartpole, state_parameters=(*cartpole.state_parameters, shade)))
    with pytest.raises(TaskError, match="state parameter 'shade': the episode is the same at"):
        run_task_code(
            bound, {"fast": {"latency": 0.0, "duration": 1.5}}, thresholds={"fall_angle": 0.5}
        )


def _config(name: str) -> dict:
    return yaml.safe_load((REPO_ROOT / "config" / name).read_text())


def _cartpole(edits: dict) -> dict:
    config = _config("cartpole_latency.yaml")
    config["conditions"] = {"edited": {"latency": 0.0, "model": edits}, "stock": {"latency": 0.0}}
    config["design"]["falsifier"].update(treatment="stock", baseline="edited")
    config.pop("sweep", None)
    config.pop("variants", None)
    return config


def _gantry(**changes) -> dict:
    config = _config("config.yaml")
    config.update(changes)
    return config


def _check(config: dict) -> str:
    with pytest.raises(ConfigError) as err:
        check_config(config, source="config/config.yaml", repo_root=REPO_ROOT)
    assert "\n" not in str(err.value)
    return str(err.value)


NOTHING = "changes nothing: the edited model simulates as the committed one"
UNDONE = "and a condition's edits apply after a variant's: the variant's run of 'fast' would keep"


def _gantry_cube_moved() -> dict:
    config = _gantry()
    config["conditions"]["fast"]["model"] = {"body": {"cube": {"pos": [0.01, 0, 0.03]}}}
    return config


def _gantry_edited(edits: dict) -> dict:
    config = _gantry()
    config["conditions"]["fast"]["model"] = edits
    config.pop("variants")
    return config


RED = {"geom": {"cube": {"rgba": [1, 0, 0, 1]}}}
NO_CHANGE = {
    # every joint of the cart-pole sets its own damping: the class's value reaches none
    "a class's value every element overrides": (
        lambda: _cartpole({"default": {"main": {"joint": {"damping": [0.3, 0, 0]}}}}),
        f"conditions.edited.model: {NOTHING}",
    ),
    "a geom's colour": (
        lambda: _cartpole({"geom": {"cart": {"rgba": [1, 0, 0, 1]}}}),
        f"conditions.edited.model: {NOTHING}",
    ),
    # the gantry resets to its keyframe: the cube's body pos (its qpos0) is never simulated
    "a free body's position under a keyframe reset": (
        _gantry_cube_moved,
        f"conditions.fast.model: {NOTHING}",
    ),
    # MuJoCo takes the larger of two geoms' frictions: the pads' torsional 0.003 and the
    # floor's 0.005 stay (a sliding friction under 0.8 would change the floor's contacts: 0.6)
    "a cube's torsional friction under the pads' and the floor's": (
        lambda: _gantry_edited({"geom": {"cube": {"friction": [0.8, 0.001, 0.0001]}}}),
        "conditions.fast.model: changes nothing: `cube` friction 0.8 0.003 0.0001 -> 0.8 0.001 "
        "0.0001; its contacts with `floor` keep friction 0.8 0.005 0.0001; its contacts with "
        "`left_pad`, `right_pad` keep friction 0.8 0.003 0.0001 (MuJoCo mixes each pair's "
        "contact parameters from its two geoms",
    ),
    "a variant's friction no contact sees": (
        lambda: _gantry(variants={"slick": {"geom": {"cube": {"friction": [0.8, 0.001, 0.0001]}}}}),
        "variants.slick: changes nothing: `cube` friction 0.8 0.003 0.0001 -> 0.8 0.001 0.0001;",
    ),
    "a variant's colour": (
        lambda: _gantry(variants={"red": RED}),
        f"variants.red: {NOTHING}",
    ),
    "two variants the same but for a colour": (
        lambda: _gantry(
            variants={
                "rk4": {"option": {"integrator": "RK4"}},
                "rk4_red": {"option": {"integrator": "RK4"}, **RED},
            }
        ),
        "variants.rk4_red: the same simulation as variants.rk4; expected each variant once",
    ),
}


@pytest.mark.parametrize("case", NO_CHANGE, ids=list(NO_CHANGE))
def test_an_edit_that_changes_no_simulation_is_refused(case):
    config, message = NO_CHANGE[case]
    assert _check(config()).startswith(f"config/config.yaml: {message}")


def test_a_condition_that_sets_a_variants_value_is_refused_naming_both():
    """Condition `fast` at 2.5 ms and variant `timestep_1ms`: the variant's run of `fast` would
    be `fast`'s own, yet counted as the variant's (item 7)."""
    config = _gantry()
    config["conditions"]["fast"]["model"] = {"option": {"timestep": 0.0025}}
    assert _check(config).startswith(
        "config/config.yaml: variants.timestep_1ms.option.timestep: condition 'fast' sets it too "
        f"(conditions.fast.model.option.timestep), {UNDONE} the condition's value, yet be counted "
        "as the variant's"
    )


def test_a_condition_that_sets_a_variants_value_under_another_name_is_refused_naming_both():
    """Issue 42 item 12: the reacher's `damping_x3` sets each joint's damping, here by address
    (`#0`, `#1`), the variant the shoulder's by name: one element, so one value both set,
    refused as when both name it alike (before, no key was shared, and only a comparison of
    the runs' simulations refused it, without naming the value)."""
    config = _config("reacher_damping.yaml")
    joints = config["conditions"]["damping_x3"]["model"]["joint"]
    joints["#0"], joints["#1"] = joints.pop("shoulder"), joints.pop("wrist")
    config["variants"] = {"damped": {"joint": {"shoulder": {"damping": [0.05, 0, 0]}}}}
    assert _check(config).startswith(
        "config/config.yaml: variants.damped.joint.shoulder.damping: condition 'damping_x3' "
        "sets it too (conditions.damping_x3.model.joint.#0.damping), and a condition's edits "
        "apply after a variant's"
    )


@pytest.mark.parametrize("other", ["#0", "on:arm"])
def test_one_element_under_two_names_in_one_condition_is_refused(other):
    """Issue 42 item 12: `shoulder` and `#0` (or `on:arm`, the one joint on the arm) are one
    joint: the last edit would win, and the report would list both."""
    config = _config("reacher_damping.yaml")
    joints = config["conditions"]["damping_x3"]["model"]["joint"]
    joints[other] = {"damping": [0.05, 0, 0]}
    assert _check(config) == (
        f"config/config.yaml: conditions.damping_x3.model.joint.{other}: the same joint as "
        "conditions.damping_x3.model.joint.shoulder; expected each element once, under one "
        "name (else the last edit would win)"
    )


def test_one_element_under_two_names_in_one_variant_is_refused():
    config = _config("reacher_damping.yaml")
    damped = {"damping": [0.05, 0, 0]}
    config["variants"] = {"damped": {"joint": {"wrist": damped, "#1": {"armature": 0.01}}}}
    assert _check(config) == (
        "config/config.yaml: variants.damped.joint.#1: the same joint as "
        "variants.damped.joint.wrist; expected each element once, under one name (else the "
        "last edit would win)"
    )


SPRING = """<mujoco><worldbody><body pos="0 0 1"><joint name="hinge" axis="0 1 0" {spring}/>
  <geom type="capsule" fromto="0 0 0 0.3 0 0" size="0.02"/></body></worldbody></mujoco>"""


@pytest.mark.parametrize("spring", ["", 'stiffness="2"'])
def test_a_rest_position_matters_only_to_a_joint_with_a_spring(spring):
    nominal = mujoco.MjModel.from_xml_string(SPRING.format(spring=spring))
    edited = copy.copy(nominal)
    edited.qpos_spring[0] = 0.4
    (h0, t0), (h1, t1) = _hash_and_trajectory(nominal), _hash_and_trajectory(edited)
    assert np.array_equal(t0, t1) == (not spring)
    assert (h0 == h1) == (not spring)


def _cartpole_conditions(conditions: dict) -> dict:
    config = _config("cartpole_latency.yaml")
    config["conditions"] = conditions
    first, second = conditions
    config["design"]["falsifier"].update(treatment=second, baseline=first)
    config.pop("sweep", None)
    config.pop("variants", None)
    return config


def test_two_conditions_that_run_alike_are_refused_naming_both():
    # the default duration spelled out: one condition under two names
    config = _cartpole_conditions(
        {"stock": {"latency": 0.0}, "again": {"latency": 0.0, "duration": 3.0}}
    )
    assert _check(config) == (
        "config/config.yaml: conditions.again: runs bit for bit as condition 'stock': the "
        "nominal episode and each state parameter at its low and its high value (the others "
        "nominal) give the same trajectories, so the two would be compared as if they differed; "
        "expected conditions that differ in what the episode does (a parameter the task reads, "
        "an edit of the physics, another policy)"
    )


def test_conditions_alike_only_at_the_nominal_state_pass():
    """The cart-pole's pole starts upright and still at its nominal state, so the policy never
    acts and latency cannot matter there: its two conditions' nominal episodes are bit for bit
    the same, yet they differ at every tilted state. Refusing on the nominal episode alone
    would refuse the built-in experiment."""
    config = _config("cartpole_latency.yaml")
    task = load_task(config["task"], repo_root=REPO_ROOT)
    bound = BoundTask.of(task, mujoco.MjModel.from_xml_path(str(REPO_ROOT / config["model"])))
    nominal = {p.name: np.array([p.nominal_value]) for p in task.state_parameters}
    physics = [
        next(iter_batches(bound, nominal, c, thresholds={"fall_angle": 0.5})).episodes.physics
        for c in config["conditions"].values()
    ]
    assert np.array_equal(physics[0], physics[1])  # the premise
    check_config(config, source="config/cartpole_latency.yaml", repo_root=REPO_ROOT)


def test_a_state_parameter_that_edits_a_friction_no_contact_sees_is_refused():
    """The gantry cube's torsional friction drawn below the pads' (0.003) and the floor's
    (0.005): MuJoCo takes the larger of two, so every episode is the same."""
    gantry = load_task("tasks/gantry_lift/task.py", repo_root=REPO_ROOT)
    torsion = StateParameter(
        "torsion", "m", 0.0005, 0.002, ModelValue("geom", "cube", "friction", 1)
    )
    bound = BoundTask.of(replace(gantry, state_parameters=(*gantry.state_parameters, torsion)))
    with pytest.raises(TaskError, match="state parameter 'torsion': the episode is the same at"):
        run_task_code(bound, {"fast": {"lift_time": 0.15}}, thresholds={})
