"""robosuite's Lift (`tasks/robosuite_lift/`): its operational-space controller at the physics
rate, through the engine, against the plain loop (bit for bit) and against robosuite's
arithmetic written for one episode (`osc_reference`, an independent implementation)."""

from __future__ import annotations

import mujoco
import numpy as np
import pytest
from mujoco import rollout
from robosuite_lift import osc_reference
from robosuite_lift.task import TASK, ScriptedLift, operational_space

from mjtrial import REPO_ROOT
from mjtrial.sim import closed_loop
from mjtrial.sim.physics import FULLPHYSICS, load_model
from mjtrial.task import BoundTask, load_task

TIMING = closed_loop.Timing(steps_per_control=25, n_controls=12)  # 0.6 s: the approach


@pytest.fixture(scope="module")
def bound() -> BoundTask:
    task = load_task(REPO_ROOT / "tasks" / "robosuite_lift" / "task.py")
    return BoundTask.of(task, load_model(task.model))


def episodes(bound: BoundTask, n: int):
    rng = np.random.default_rng(3)
    scratch = mujoco.MjData(bound.model)
    out = []
    for _ in range(n):
        values = {
            "cube_dx": rng.uniform(-0.03, 0.03),
            "cube_dy": rng.uniform(-0.03, 0.03),
            "cube_yaw": rng.uniform(0, 2 * np.pi),
        } | {f"joint{k + 1}_noise": rng.normal(0, 0.02) for k in range(7)}
        out.append(bound.episode(values, scratch=scratch))
    return [m for m, _ in out], np.stack([s for _, s in out])


def observe(bound: BoundTask):
    return bound.observer(TASK.controller.observations, {}, params={}, n_controls=12)


def run(bound, models, initial, *, split, nthread):
    out = []
    for rows in np.split(np.arange(len(models)), split):
        with rollout.Rollout(nthread=0) as runner:
            out.append(
                closed_loop.run_batch(
                    [models[i] for i in rows],
                    initial[rows],
                    ScriptedLift(3),
                    observe(bound),
                    TIMING,
                    runner=runner,
                    datas=[mujoco.MjData(bound.model) for _ in range(nthread)],
                    low_level=lambda: operational_space(bound.model, {}),
                )
            )
    return np.concatenate([b.physics for b in out]), np.concatenate([b.applied for b in out])


def test_the_panda_through_the_engine_equals_the_plain_loop_bit_for_bit(bound):
    models, initial = episodes(bound, 3)
    physics, applied = run(bound, models, initial, split=[], nthread=1)
    for split, nthread in (([1, 2], 1), ([2], 2)):
        again, _ = run(bound, models, initial, split=split, nthread=nthread)
        np.testing.assert_array_equal(again, physics)
    for i in range(1):
        ref = closed_loop.reference_episode(
            models[i],
            initial[i],
            ScriptedLift(3),
            observe(bound),
            TIMING,
            low_level=lambda: operational_space(bound.model, {}),
        )
        np.testing.assert_array_equal(physics[i], ref.physics[0])
        np.testing.assert_array_equal(applied[i], ref.applied[0])
    # the arm moved toward the cube, the torques changing within each action
    assert np.abs(np.diff(applied[:, :25, 0], axis=1)).max() > 1e-3


def test_the_batched_controller_is_robosuites_arithmetic(bound):
    """`OperationalSpace` on a batch against `osc_reference` (robosuite's OSC_POSE and GRIP
    written out for one episode, as robosuite writes them): the same controls at the first
    step to rounding, the same grip-site path to a micrometre after 0.6 s."""
    models, initial = episodes(bound, 3)
    physics, applied = run(bound, models, initial, split=[], nthread=1)
    model = bound.model
    ids = osc_reference.Ids.of(model)
    grip = model.site(osc_reference.GRIP_SITE).id
    for i in range(len(models)):
        d = mujoco.MjData(models[i])
        mujoco.mj_setState(models[i], d, initial[i], FULLPHYSICS)
        state = osc_reference.start(models[i], d, ids)
        policy = ScriptedLift(3)
        policy.reset(1)
        observe_one = observe(bound)
        first = None
        for k in range(TIMING.n_controls):
            row = np.empty(len(initial[i]))
            mujoco.mj_getState(models[i], d, row, FULLPHYSICS)
            action = policy(observe_one.read(k, row[None], None))[0]
            for j in range(TIMING.steps_per_control):
                mujoco.mj_step1(models[i], d)
                u = osc_reference.ctrl(models[i], d, ids, state, action, j == 0)
                first = u if first is None else first
                d.ctrl[:] = u
                mujoco.mj_step2(models[i], d)
        np.testing.assert_allclose(applied[i, 0], first, rtol=0, atol=1e-9)
        end = mujoco.MjData(models[i])
        mujoco.mj_setState(models[i], end, physics[i, -1], FULLPHYSICS)
        mujoco.mj_kinematics(models[i], end)
        mujoco.mj_kinematics(models[i], d)
        assert np.abs(end.site_xpos[grip] - d.site_xpos[grip]).max() < 1e-6
