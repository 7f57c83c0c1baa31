"""Episode values everywhere: a goal drawn per episode moves the third-party reacher's own target
geom, the policy is told it, and the success test reads it; checked against a plain `mj_step`
loop written from the task's declarations, with MuJoCo's own fingertip position."""

from __future__ import annotations

import copy

import mujoco
import numpy as np
import pytest
from conftest import REPO_ROOT

from mjtrial.sim.engine import iter_batches
from mjtrial.task import (
    BoundTask,
    MocapPosition,
    ModelValue,
    Observation,
    Rotation,
    StateParameter,
    TaskError,
    load_task,
)

REACHER = REPO_ROOT / "tasks" / "reacher_goal" / "task.py"
CONDITION = {"latency": 0.06, "kp": 1.0, "duration": 1.1}


@pytest.fixture(scope="module")
def reacher():
    return BoundTask.of(load_task(REACHER))


def _states(task, n: int, seed: int = 3) -> dict[str, np.ndarray]:
    rng = np.random.default_rng(seed)
    return {p.name: rng.uniform(p.low, p.high, n) for p in task.state_parameters}


def _plain_episode(task_module, model: mujoco.MjModel, values: dict[str, float]):
    """One episode as a researcher writes it: move the target, reset, set the start angles, then
    every control period read the encoders as they were `latency` ago, call the policy, step."""
    m = copy.copy(model)
    target = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_GEOM, "target")
    m.geom_pos[target, 0], m.geom_pos[target, 1] = values["goal_x"], values["goal_y"]
    d = mujoco.MjData(m)
    mujoco.mj_resetData(m, d)
    d.qpos[0] += values["shoulder_start"]
    d.qpos[1] += values["wrist_start"]
    params = {"control_period": 0.02, **CONDITION}
    per_control = round(params["control_period"] / m.opt.timestep)
    latency = round(params["latency"] / m.opt.timestep)
    policy = task_module.JointPD(model, params["kp"], params["control_period"])
    policy.reset(1)
    qpos_history = [d.qpos[:2].copy()]  # index j: after j steps
    finger = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_GEOM, "finger")
    fingertip = []
    for k in range(round(params["duration"] / params["control_period"])):
        seen = qpos_history[max(0, k * per_control - latency)]
        obs = np.array([[seen[0], seen[1], values["goal_x"], values["goal_y"]]])
        d.ctrl[:] = policy(obs)[0]
        for _ in range(per_control):
            mujoco.mj_step(m, d)
            qpos_history.append(d.qpos[:2].copy())
            mujoco.mj_forward(m, d)
            fingertip.append(d.geom_xpos[finger, :2].copy())
    return np.array(qpos_history[1:]), np.array(fingertip)


def test_the_goal_reaches_the_model_the_policy_and_the_success_test(reacher):
    import importlib.util

    spec = importlib.util.spec_from_file_location("reacher_task_module", REACHER)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    values = _states(reacher.task, 6)
    batches = list(iter_batches(reacher, values, CONDITION, thresholds={}))
    physics = np.concatenate([b.episodes.physics for b in batches])
    outcome = {k: np.concatenate([b.outcome[k] for b in batches]) for k in batches[0].outcome}
    for i in range(6):
        episode = {k: float(v[i]) for k, v in values.items()}
        qpos, fingertip = _plain_episode(module, reacher.model, episode)
        np.testing.assert_array_equal(physics[i, :, 1:3], qpos)
        goal = np.array([episode["goal_x"], episode["goal_y"]])
        judged = np.linalg.norm(fingertip[-25:] - goal, axis=1)  # the last 0.5 s of 20 ms steps
        assert outcome["success"][i] == bool((judged < 0.05).all())
        assert outcome["final_distance"][i] == pytest.approx(judged[-1], abs=1e-9)


def test_results_do_not_depend_on_the_batch(reacher):
    values = _states(reacher.task, 10, seed=11)
    whole = [b.outcome for b in iter_batches(reacher, values, CONDITION, thresholds={})]
    split = [
        b.outcome for b in iter_batches(reacher, values, CONDITION, thresholds={}, batch_size=3)
    ]
    for key in ("success", "final_distance", "worst_distance"):
        np.testing.assert_array_equal(
            np.concatenate([o[key] for o in whole]), np.concatenate([o[key] for o in split])
        )


def test_an_episode_value_observation_of_no_state_parameter_is_one_line(reacher):
    task = reacher.task
    bad = Observation.episode_value("goal_z", "goal_z", source="the goal")
    broken = type(task)(**{**task.__dict__, "observations": (*task.observations, bad)})
    with pytest.raises(TaskError, match=r"observation 'goal_z': expected one of the state"):
        BoundTask.of(broken)


@pytest.mark.parametrize(
    ("applier", "message"),
    [
        (ModelValue("geom", "goal", "pos", 0), "expected a geom named 'goal'"),
        (ModelValue("geom", "target", "poss", 0), "expected a numeric field 'poss'"),
        (ModelValue("geom", "target", "pos", 3), r"with an index 3 \(it has 3 numbers\)"),
        (ModelValue("gem", "target", "pos", 0), "expected an MjModel element kind, got 'gem'"),
    ],
)
def test_a_model_value_naming_nothing_is_one_line(reacher, applier, message):
    task = reacher.task
    parameter = StateParameter("goal_x", "m", -0.2, 0.2, applier)
    broken = type(task)(**{**task.__dict__, "state_parameters": (parameter,)})
    with pytest.raises(TaskError, match=message):
        BoundTask.of(broken)


def test_a_mocap_position_moves_the_mocap_body_in_the_reset_data():
    model = mujoco.MjModel.from_xml_string(
        '<mujoco><worldbody><body name="goal" mocap="true"><geom size=".01"/></body>'
        '<body><freejoint/><geom size=".1"/></body></worldbody></mujoco>'
    )
    apply = MocapPosition("goal", 1).bind(model)
    data = mujoco.MjData(model)
    apply(model, data, 0.25)
    assert data.mocap_pos[0].tolist() == [0.0, 0.25, 0.0]
    with pytest.raises(TaskError, match="expected body 'world' to be a mocap body"):
        MocapPosition("world", 0).bind(model)


@pytest.mark.parametrize("task_file", ["gantry_lift/task.py", "reacher_goal/task.py"])
def test_a_reused_model_copy_is_the_model_a_fresh_copy_would_be(task_file):
    """Model parameters that set their value (a mass, a goal's position) let the engine reuse
    a batch slot's copy: after other episodes, the same compiled bytes (MJB) and initial state
    as a fresh copy's."""
    import hashlib
    import tempfile
    from pathlib import Path

    bound = BoundTask.of(load_task(REPO_ROOT / "tasks" / task_file))
    assert bound.reuses_models
    scratch, slot = mujoco.MjData(bound.model), copy.copy(bound.model)
    values = _states(bound.task, 5, seed=4)

    def mjb(model) -> str:
        with tempfile.TemporaryDirectory() as folder:
            mujoco.mj_saveModel(model, str(Path(folder) / "m.mjb"), None)
            return hashlib.sha256((Path(folder) / "m.mjb").read_bytes()).hexdigest()

    for i in range(5):
        episode = {k: float(v[i]) for k, v in values.items()}
        fresh, fresh_state = bound.episode(episode, scratch=scratch)
        reused, reused_state = bound.episode(episode, scratch=scratch, model=slot)
        assert reused is slot and fresh is not bound.model
        assert mjb(reused) == mjb(fresh)
        np.testing.assert_array_equal(reused_state, fresh_state)


def test_a_custom_model_parameter_gets_a_fresh_copy_every_episode(reacher):
    from mjtrial.task import Custom

    task = reacher.task

    def scale(m, d, value):  # multiplies: a reused copy would compound
        m.geom_size[0, 0] *= value

    parameter = StateParameter("scale", "", 0.5, 2.0, Custom(scale, stage="model"))
    parameters = (*task.state_parameters, parameter)
    bound = BoundTask.of(type(task)(**{**task.__dict__, "state_parameters": parameters}))
    assert not bound.reuses_models
    slot = copy.copy(bound.model)
    values = {p.name: 0.1 for p in parameters}
    model, _ = bound.episode(values, scratch=mujoco.MjData(bound.model), model=slot)
    assert model is not slot


ROTATED = """<mujoco><worldbody>
  <body name="arm" pos="0.1 0 0" {body}><joint type="hinge" axis="0 0 1"/>
    <geom name="marker" type="box" size=".05 .02 .01" pos=".1 0 0" {geom}/>
    <site name="tip" pos=".2 0 0" {site}/></body>
  <body name="goal" mocap="true" {goal}><geom size=".01"/></body>
</worldbody></mujoco>"""


def _rotated(**euler: str) -> mujoco.MjModel:
    """The model with MuJoCo's own `euler` attribute (radians, the default xyz sequence of
    intrinsic rotations) written on the named elements: the reference for `Rotation`."""
    attrs = {k: f'euler="{v}"' for k, v in euler.items()}
    xml = ROTATED.format(**{k: attrs.get(k, "") for k in ("body", "geom", "site", "goal")})
    return mujoco.MjModel.from_xml_string(
        xml.replace("<mujoco>", '<mujoco><compiler angle="radian"/>')
    )


@pytest.mark.parametrize(
    ("kind", "name", "key", "axis"),
    [
        ("body", "arm", "body", 2),
        ("geom", "marker", "geom", 1),
        ("site", "tip", "site", 0),
        ("body", "goal", "goal", 2),
    ],
)
def test_a_rotation_turns_an_element_as_the_models_own_euler_attribute_does(kind, name, key, axis):
    angles = ["0", "0", "0"]
    angles[axis] = "0.7"
    reference = _rotated(**{key: " ".join(angles)})
    model = _rotated()
    data = mujoco.MjData(model)
    apply = Rotation(kind, name, axis).bind(model)
    apply(model, data, 0.3)  # a reused copy: the value is set from the nominal, not added
    apply(model, data, 0.7)
    mujoco.mj_forward(model, data)
    expected = mujoco.MjData(reference)
    mujoco.mj_forward(reference, expected)
    for field in ("xquat", "geom_xmat", "site_xpos", "site_xmat", "geom_xpos"):
        np.testing.assert_allclose(getattr(data, field), getattr(expected, field), atol=1e-12)
    if name == "goal":
        np.testing.assert_allclose(data.mocap_quat[0], reference.body_quat[2], atol=1e-12)


def test_a_rotation_names_a_wrong_kind_axis_or_element():
    model = _rotated()
    with pytest.raises(TaskError, match="kind: expected one of"):
        Rotation("joint", "arm", 0).bind(model)
    with pytest.raises(TaskError, match="axis: expected 0, 1 or 2, got 3"):
        Rotation("body", "arm", 3).bind(model)
    with pytest.raises(TaskError, match="marker2"):
        Rotation("geom", "marker2", 0).bind(model)


def test_a_model_value_moves_a_geom_compiled_at_its_bodys_frame():
    """MuJoCo's compiler marks a geom or site without a pos or quat of its own as sharing its
    body's frame, and kinematics then ignores its pos: a moved goal would stay put."""
    plain = '<mujoco><worldbody><body name="b" pos=".1 0 0"><geom name="g" size=".01"/>'
    plain += '<site name="s"/></body></worldbody></mujoco>'
    model = mujoco.MjModel.from_xml_string(plain)
    data = mujoco.MjData(model)
    ModelValue("geom", "g", "pos", 1).bind(model)(model, data, 0.25)
    ModelValue("site", "s", "pos", 2).bind(model)(model, data, -0.5)
    mujoco.mj_forward(model, data)
    reference = mujoco.MjModel.from_xml_string(
        plain.replace('name="g"', 'name="g" pos="0 .25 0"').replace(
            'name="s"', 'name="s" pos="0 0 -.5"'
        )
    )
    expected = mujoco.MjData(reference)
    mujoco.mj_forward(reference, expected)
    np.testing.assert_allclose(data.geom_xpos, expected.geom_xpos, atol=1e-15)
    np.testing.assert_allclose(data.site_xpos, expected.site_xpos, atol=1e-15)
