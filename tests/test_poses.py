"""Poses as observations (`Observation.body_position` and its siblings, `mjtrial.task.poses`) on
the Fetch model, against a plain MjData loop written here; and an observation's own number of
columns everywhere (a `framepos` sensor has 3), in the preflight and a policy file's contract."""

from __future__ import annotations

import copy
import dataclasses

import mujoco
import numpy as np
import pytest
from conftest import REPO_ROOT
from mujoco import rollout
from policy_graphs import tanh_mlp, write

from mjtrial.policy_files.file import PolicyFileError, load_policy_file
from mjtrial.sim.closed_loop import Timing, reference_episode, run_batch
from mjtrial.sim.engine import iter_batches
from mjtrial.sim.physics import FULLPHYSICS, load_model
from mjtrial.task import (
    BoundTask,
    ClosedLoop,
    ModelValue,
    Observation,
    StateParameter,
    Task,
    TaskError,
    load_task,
)
from mjtrial.task.checks import run_task_code

FETCH = REPO_ROOT / "tasks" / "fetch_pick" / "assets" / "fetch" / "pick_and_place.xml"
REACHER = REPO_ROOT / "tasks" / "reacher_goal" / "task.py"
CARTPOLE = REPO_ROOT / "tasks" / "cartpole_latency" / "task.py"
N_CONTROLS = 8


class Recorder:
    """Gripper fingers driven by a fixed command; keeps every observation it is given."""

    def __init__(self):
        self.seen = []

    def reset(self, n):
        self.seen = []

    def __call__(self, obs):
        self.seen.append(obs.copy())
        return np.tile([0.03, -0.02], (len(obs), 1))


POSES = (
    Observation.body_position("gripper", "robot0:gripper_link", source="forward kinematics"),
    Observation.site_position("object", "object0", source="camera"),
    Observation.site_position("target", "target0", source="the goal it is commanded"),
    Observation.body_orientation("gripper_q", "robot0:gripper_link", source="kinematics"),
    Observation.site_orientation("object_q", "object0", source="camera"),
    Observation.site_position(
        "object_in_gripper", "object0", source="x", frame="robot0:gripper_link"
    ),
    Observation.body_orientation(
        "object_q_in_gripper", "object0", source="x", frame="robot0:gripper_link"
    ),
    Observation.free_joint("object_pose", "object0:joint", source="camera"),
)


def _fetch_task(observations=POSES) -> Task:
    """Fetch with the object's table offset drawn per episode (a model parameter: its body's
    position), and a recorder for a policy."""
    return Task(
        name="fetch_poses",
        title="poses",
        model=FETCH,
        state_parameters=(
            StateParameter("table_x", "m", 1.2, 1.4, ModelValue("body", "table0", "pos", 0)),
            StateParameter(
                "lift", "m", 0.0, 0.05, ModelValue("body", "robot0:base_link", "pos", 2)
            ),
        ),
        protocol_parameters=(),
        controller=ClosedLoop(
            policy=lambda model, params: Recorder(),
            observations=tuple(o.name for o in observations),
            timing=lambda model, params: Timing(5, N_CONTROLS),
        ),
        success=lambda e: np.ones(len(e.physics), dtype=bool),
        measure=lambda e: {},
        observations=observations,
    )


def _expected(model: mujoco.MjModel, d: mujoco.MjData) -> np.ndarray:
    """The pose observations of `POSES` from data after mj_forward, by MuJoCo's own pose math."""
    body = lambda n: mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_BODY, n)  # noqa: E731
    site = lambda n: mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_SITE, n)  # noqa: E731
    g, obj, tgt = body("robot0:gripper_link"), site("object0"), site("target0")
    object_q = np.empty(4)
    mujoco.mju_mat2Quat(object_q, d.site_xmat[obj])
    inverse_pos, inverse_q = np.empty(3), np.empty(4)
    mujoco.mju_negPose(inverse_pos, inverse_q, d.xpos[g], d.xquat[g])
    rel_pos, rel_q = np.empty(3), np.empty(4)
    mujoco.mju_mulPose(rel_pos, rel_q, inverse_pos, inverse_q, d.site_xpos[obj], object_q)
    joint = model.jnt_qposadr[mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_JOINT, "object0:joint")]
    return np.concatenate(
        [
            d.xpos[g],
            d.site_xpos[obj],
            d.site_xpos[tgt],
            d.xquat[g],
            object_q,
            rel_pos,
            rel_q,
            d.qpos[joint : joint + 7],
        ]
    )


def _values(task, n, seed=3):
    rng = np.random.default_rng(seed)
    return {p.name: rng.uniform(p.low, p.high, n) for p in task.state_parameters}


@pytest.fixture(scope="module")
def fetch_batch():
    task = _fetch_task()
    bound = BoundTask.of(task)
    values = _values(task, 3)
    scratch = mujoco.MjData(bound.model)
    episodes = [
        bound.episode({k: v[i] for k, v in values.items()}, scratch=scratch) for i in range(3)
    ]
    models, initial = [m for m, _ in episodes], np.stack([s for _, s in episodes])
    observer = bound.observer(task.controller.observations, values, models=models)
    policy, timing = Recorder(), Timing(5, N_CONTROLS, 2)
    with rollout.Rollout(nthread=0) as runner:
        batch = run_batch(
            models, initial, policy, observer, timing, runner=runner, datas=[scratch], check=False
        )
    return bound, values, models, initial, batch, policy, timing


def test_poses_are_the_plain_loops_on_each_episodes_model(fetch_batch):
    bound, values, models, initial, batch, policy, timing = fetch_batch
    states = np.concatenate([initial[:, None], batch.physics], axis=1)
    d = mujoco.MjData(bound.model)
    for i in range(3):
        for k in range(N_CONTROLS):
            mujoco.mj_setState(models[i], d, states[i, timing.measured_step(k)], FULLPHYSICS)
            mujoco.mj_forward(models[i], d)
            expected = _expected(models[i], d)
            got = policy.seen[k][i]
            np.testing.assert_array_equal(got[:17], expected[:17])  # read as MuJoCo gives them
            np.testing.assert_allclose(got[17:24], expected[17:24], rtol=0, atol=1e-12)
            np.testing.assert_array_equal(got[24:], expected[24:])
    # the per-episode model matters: the base's height moves the gripper
    assert np.ptp(policy.seen[0][:, 2]) > 0.005
    assert policy.seen[0].shape == (3, 31)


def test_the_engine_equals_the_reference_bit_for_bit(fetch_batch):
    """Constraints off (the weld and contacts: `mujoco.rollout` and `mj_step` differ by the
    solver's warm start otherwise), the observations are the same bits both ways."""
    bound, values, models, initial, batch, _, timing = fetch_batch
    models = [copy.copy(m) for m in models]
    for m in models:
        m.opt.disableflags |= mujoco.mjtDisableBit.mjDSBL_CONSTRAINT
    for i in range(3):
        observer = bound.observer(
            bound.task.controller.observations,
            {k: v[i : i + 1] for k, v in values.items()},
            models=models[i : i + 1],
        )
        policy = Recorder()
        reference_episode(models[i], initial[i], policy, observer, timing)
        engine = Recorder()
        with rollout.Rollout(nthread=0) as runner:
            run_batch(
                models[i : i + 1],
                initial[i : i + 1],
                engine,
                bound.observer(bound.task.controller.observations, models=models[i : i + 1]),
                timing,
                runner=runner,
                datas=[mujoco.MjData(models[i])],
                check=False,
            )
        np.testing.assert_array_equal(np.stack(policy.seen), np.stack(engine.seen))
        assert np.ptp(np.stack(engine.seen)[:, 0, :3]) > 0  # the arm moves: steps were taken


def test_iter_batches_reads_poses_on_each_episodes_model():
    task = _fetch_task()
    bound = BoundTask.of(task)
    [batch] = iter_batches(bound, _values(task, 2), {}, thresholds={})
    assert batch.episodes.physics.shape[0] == 2
    run_task_code(bound, {"nominal": {}}, thresholds={})


@pytest.mark.parametrize(
    ("observation", "message"),
    [
        (
            Observation.body_position("mocap", "robot0:mocap", source="x"),
            "observation 'mocap': body 'robot0:mocap' is or moves with a mocap body",
        ),
        (
            Observation.site_position("t", "target0", source="x", frame="robot0:mocap"),
            "observation 't': body 'robot0:mocap' is or moves with a mocap body",
        ),
        (
            Observation.site_position("t", "target00", source="x"),
            "observation 't': expected a site named 'target00' in the model",
        ),
        (
            Observation.free_joint("f", "robot0:slide0", source="x"),
            "observation 'f': joint 'robot0:slide0' is a slide joint; expected a free joint",
        ),
    ],
)
def test_a_pose_that_cannot_be_read_is_one_line(observation, message):
    with pytest.raises(TaskError, match=message) as err:
        BoundTask.of(_fetch_task((observation,)))
    assert "\n" not in str(err.value)


# --- an observation's own number of columns ------------------------------------------------


def _reacher_with_tip(policy):
    """The reacher reading a `framepos` sensor (3 columns) added to its model, then its joints
    and goal (7 columns in all), with `policy`."""
    task = load_task(REACHER)
    spec = mujoco.MjSpec.from_file(str(task.model))
    spec.body("finger").add_site(name="fingertip")
    spec.add_sensor(
        name="tip",
        type=mujoco.mjtSensor.mjSENS_FRAMEPOS,
        objtype=mujoco.mjtObj.mjOBJ_SITE,
        objname="fingertip",
    )
    observations = (Observation.sensor("tip", "tip", source="motion capture"), *task.observations)
    task = dataclasses.replace(
        task,
        observations=observations,
        controller=dataclasses.replace(
            task.controller,
            policy=lambda model, params: policy,
            observations=tuple(o.name for o in observations),
        ),
    )
    return BoundTask.of(task, spec.compile())


class ReadsColumn:
    """Torques from one observation column (elementwise: batch independent)."""

    def __init__(self, column):
        self.column = column

    def reset(self, n):
        pass

    def __call__(self, obs):
        return np.stack([-0.1 * obs[:, self.column], 0.1 * obs[:, 0]], axis=1)


def test_a_framepos_observation_has_its_three_columns_in_the_preflight_and_an_episode():
    bound = _reacher_with_tip(ReadsColumn(6))  # the goal's y: column 6 of 7
    assert bound.widths(bound.task.controller.observations) == [3, 1, 1, 1, 1]
    run_task_code(bound, {"nominal": {}}, thresholds={})
    [batch] = iter_batches(
        bound,
        {p.name: np.array([p.nominal_value]) for p in bound.task.state_parameters},
        {},
        thresholds={},
    )
    assert batch.episodes.physics.shape[0] == 1


def test_a_policy_reading_past_its_input_is_one_line():
    bound = _reacher_with_tip(ReadsColumn(7))
    with pytest.raises(
        TaskError,
        match=r"policy raised IndexError on a batch of its "
        r"observations, 7 columns \(tip 3, shoulder_angle 1",
    ) as err:
        run_task_code(bound, {"nominal": {}}, thresholds={})
    assert "\n" not in str(err.value) and str(REACHER) in str(err.value)


def test_a_policy_files_input_is_sized_by_the_sensors_dimension(tmp_path):
    """A contract reading a 3-column `framepos` and the cart's encoder needs 4 input columns:
    a graph of 2 (what sizing every sensor as 1 column gave) is refused in one line."""
    task = load_task(CARTPOLE)
    spec = mujoco.MjSpec.from_file(str(task.model))
    spec.body("pole").add_site(name="pole_tip")
    spec.add_sensor(
        name="tip",
        type=mujoco.mjtSensor.mjSENS_FRAMEPOS,
        objtype=mujoco.mjtObj.mjOBJ_SITE,
        objname="pole_tip",
    )
    model_file = tmp_path / "cartpole_tip.xml"
    model_file.write_text(spec.to_xml())
    assert load_model(model_file).nsensordata == spec.compile().nsensordata
    task = dataclasses.replace(
        task,
        model=model_file,
        observations=(*task.observations, Observation.sensor("tip", "tip", source="camera")),
    )
    observations = ["cart_position", "tip"]
    small = write(tmp_path / "a", "small", tanh_mlp([2, 8, 1]), observations=observations)
    with pytest.raises(
        PolicyFileError, match=r"has 2 columns; expected 4 \(the 4 observation"
    ) as err:
        load_policy_file(small, task)
    assert "\n" not in str(err.value)
    fits = write(tmp_path / "b", "fits", tanh_mlp([4, 8, 1]), observations=observations)
    assert load_policy_file(fits, task).observations == tuple(observations)
