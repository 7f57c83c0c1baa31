"""A low-level controller at the physics rate (`mjtrial.sim.low_level`): the engine's episodes equal
the plain `mj_step1` / controller / `mj_step2` loop's bit for bit, whatever the batch and the
threads, on a third-party arm (dm_control's manipulator, byte for byte)."""

from __future__ import annotations

from pathlib import Path

import mujoco
import numpy as np
import pytest
from mujoco import rollout

from mjtrial.sim import closed_loop
from mjtrial.sim.controllers import JointImpedance
from mjtrial.sim.low_level import ControllerError, Reads, check_rows_alone
from mjtrial.sim.physics import FULLPHYSICS, load_model

MANIPULATOR = Path(__file__).parent / "models" / "dm_manipulator" / "manipulator.xml"
ARM = ("root", "shoulder", "elbow", "wrist")
KP, KD, SCALE = 6.0, 0.4, 0.3


@pytest.fixture(scope="module")
def model() -> mujoco.MjModel:
    return load_model(MANIPULATOR)


class Wave:
    """A policy of the arm's joint angles alone, row by row: an action that moves every joint
    toward a wave of its own angle."""

    def reset(self, n: int) -> None:
        pass

    def __call__(self, observations: np.ndarray) -> np.ndarray:
        return np.sin(3.0 * observations + 1.0)


def initial_states(model: mujoco.MjModel, n: int) -> np.ndarray:
    rng = np.random.default_rng(7)
    data = mujoco.MjData(model)
    out = np.empty((n, mujoco.mj_stateSize(model, FULLPHYSICS)))
    joints = [model.joint(f"arm_{a}").qposadr[0] for a in ARM]
    for i in range(n):
        mujoco.mj_resetData(model, data)
        data.qpos[joints] = rng.uniform(-0.6, 0.6, len(joints))
        data.qvel[model.joint("arm_root").dofadr[0]] = rng.uniform(-1, 1)
        mujoco.mj_getState(model, data, out[i], FULLPHYSICS)
    return out


def observe(model):
    joints = np.array([1 + model.joint(f"arm_{a}").qposadr[0] for a in ARM])
    return lambda states: states[:, joints]


def make(model):
    return lambda: JointImpedance(model, ARM, kp=KP, kd=KD, scale=SCALE)


TIMING = closed_loop.Timing(steps_per_control=10, n_controls=40)


def engine(model, initial, *, batch: int, nthread: int):
    out = []
    for start in range(0, len(initial), batch):
        rows = initial[start : start + batch]
        with rollout.Rollout(nthread=0) as runner:
            out.append(
                closed_loop.run_batch(
                    [model] * len(rows),
                    rows,
                    Wave(),
                    observe(model),
                    TIMING,
                    runner=runner,
                    datas=[mujoco.MjData(model) for _ in range(nthread)],
                    low_level=make(model),
                )
            )
    return out


@pytest.mark.parametrize(("batch", "nthread"), [(7, 1), (3, 1), (7, 2), (4, 3)])
def test_the_engine_equals_the_plain_loop_bit_for_bit(model, batch, nthread):
    initial = initial_states(model, 7)
    batches = engine(model, initial, batch=batch, nthread=nthread)
    physics = np.concatenate([b.physics for b in batches])
    sensordata = np.concatenate([b.sensordata for b in batches])
    applied = np.concatenate([b.applied for b in batches])
    actions = np.concatenate([b.ctrl for b in batches])
    for i, state in enumerate(initial):
        ref = closed_loop.reference_episode(
            model, state, Wave(), observe(model), TIMING, low_level=make(model)
        )
        np.testing.assert_array_equal(physics[i], ref.physics[0])
        np.testing.assert_array_equal(sensordata[i], ref.sensordata[0])
        np.testing.assert_array_equal(applied[i], ref.applied[0])
        np.testing.assert_array_equal(actions[i], ref.ctrl[0])
    # the controller really acted, every step: torques vary within a control period
    assert np.abs(np.diff(applied[:, :10], axis=1)).max() > 1e-3


def test_the_plain_loop_is_mj_step_with_the_controller_as_mjcb_control(model):
    """An independent reference: `mj_step` with the impedance law written out per joint in a
    control callback (MuJoCo calls it after the velocity stage), the same policy per period."""
    state = initial_states(model, 1)[0]
    ref = closed_loop.reference_episode(
        model, state, Wave(), observe(model), TIMING, low_level=make(model)
    )
    m = load_model(MANIPULATOR)
    d = mujoco.MjData(m)
    mujoco.mj_setState(m, d, state, FULLPHYSICS)
    act = [m.actuator(a).id for a in ARM]
    qadr = [m.jnt_qposadr[m.actuator_trnid[a, 0]] for a in act]
    dadr = [m.jnt_dofadr[m.actuator_trnid[a, 0]] for a in act]
    goal = np.zeros(len(act))
    new = {"action": None}

    def control(m, d):
        if new["action"] is not None:
            for k in range(len(act)):
                goal[k] = d.qpos[qadr[k]] + SCALE * new["action"][k]
            new["action"] = None
        for k, a in enumerate(act):
            tau = KP * (goal[k] - d.qpos[qadr[k]]) - KD * d.qvel[dadr[k]] + d.qfrc_bias[dadr[k]]
            d.ctrl[a] = min(max(tau / m.actuator_gear[a, 0], -1.0), 1.0)

    rows = []
    mujoco.set_mjcb_control(control)
    try:
        for k in range(TIMING.n_controls):
            j = k * TIMING.steps_per_control
            measured = state if j == 0 else rows[j - 1]
            new["action"] = Wave()(measured[None, [1 + q for q in qadr]])[0]
            for _ in range(TIMING.steps_per_control):
                mujoco.mj_step(m, d)
                row = np.empty(len(state))
                mujoco.mj_getState(m, d, row, FULLPHYSICS)
                rows.append(row)
    finally:
        mujoco.set_mjcb_control(None)
    np.testing.assert_array_equal(np.stack(rows), ref.physics[0])


def test_a_controller_reading_a_missing_site_is_named(model):
    class Reader(JointImpedance):
        reads = Reads(sites=("no_such_site",))

    with rollout.Rollout(nthread=0) as runner, pytest.raises(ControllerError, match="no_such_site"):
        closed_loop.run_batch(
            [model],
            initial_states(model, 1),
            Wave(),
            observe(model),
            TIMING,
            runner=runner,
            datas=[mujoco.MjData(model)],
            low_level=lambda: Reader(model, ARM, kp=KP, kd=KD, scale=SCALE),
        )


def test_a_controller_whose_rows_depend_on_the_batch_is_refused(model):
    class Mixing(JointImpedance):
        def __call__(self, view, action, new_action):
            return super().__call__(view, action + action.mean(axis=0), new_action)

    initial = initial_states(model, 1)[0]
    check_rows_alone(make(model), model, initial)  # the honest one passes
    with pytest.raises(ControllerError, match="row 0 alone gives other controls"):
        check_rows_alone(lambda: Mixing(model, ARM, kp=KP, kd=KD, scale=SCALE), model, initial)


def test_an_episode_that_goes_unstable_halts_where_the_plain_loop_halts():
    """A timestep of 5 s, far too long for the arm: MuJoCo warns (bad accelerations) and the
    episode stops there, its state repeated, in the engine as in the plain loop."""
    model = load_model(MANIPULATOR)
    model.opt.timestep = 5.0
    initial = initial_states(model, 3)
    with rollout.Rollout(nthread=0) as runner:
        batch = closed_loop.run_batch(
            [model] * 3,
            initial,
            Wave(),
            observe(model),
            TIMING,
            runner=runner,
            datas=[mujoco.MjData(model)],
            low_level=make(model),
        )
    frozen = np.all(batch.physics[:, -1] == batch.physics[:, -2], axis=1)
    assert frozen.any()
    for i, state in enumerate(initial):
        ref = closed_loop.reference_episode(
            model, state, Wave(), observe(model), TIMING, low_level=make(model)
        )
        assert ref.warnings.any() == frozen[i]
        np.testing.assert_array_equal(batch.physics[i], ref.physics[0])
        np.testing.assert_array_equal(batch.applied[i], ref.applied[0])


SLIDER = """
<mujoco>
  <option timestep="10" gravity="0 0 0"/>
  <worldbody>
    <body name="slider">
      <joint name="x" type="slide" axis="1 0 0"/>
      <geom type="sphere" size="0.1" mass="1"/>
    </body>
  </worldbody>
  <actuator><motor name="push" joint="x"/></actuator>
  <sensor><jointpos joint="x"/><jointvel joint="x"/></sensor>
</mujoco>
"""


class Kick:
    """Pushes the slider hard from time 30 on: after that step its qpos and qvel are beyond
    MuJoCo's bound with no warning yet (the acceleration is within it), so the next `mj_step1`
    warns and resets its data, time included; before, a nudge by the action."""

    reads = Reads()
    n_inputs = 1

    def reset(self, models) -> None:
        pass

    def __call__(self, view, action, new_action):
        return np.where(view.time[:, None] >= 30.0, 5e9, 1e-3 * action)


def test_an_episode_whose_state_goes_bad_is_reset_by_mj_step1_as_in_the_plain_loop():
    """The engine takes a step's time, qpos and qvel from the state the step before left, which
    `mj_step1` keeps unless it is bad: then it resets the data, and the controller sees (and
    the episode halts at) what the plain loop's does. The second episode starts at time -1000
    and never kicks, stepping on beside the halted one."""
    model = mujoco.MjModel.from_xml_string(SLIDER)
    initial = np.zeros((2, mujoco.mj_stateSize(model, FULLPHYSICS)))
    initial[1, 0] = -1000.0
    timing = closed_loop.Timing(steps_per_control=2, n_controls=4)
    with rollout.Rollout(nthread=0) as runner:
        batch = closed_loop.run_batch(
            [model] * 2,
            initial,
            Wave(),
            lambda states: states[:, 1:2],
            timing,
            runner=runner,
            datas=[mujoco.MjData(model)],
            low_level=Kick,
        )
    for i, state in enumerate(initial):
        ref = closed_loop.reference_episode(
            model, state, Wave(), lambda states: states[:, 1:2], timing, low_level=Kick
        )
        np.testing.assert_array_equal(batch.physics[i], ref.physics[0])
        np.testing.assert_array_equal(batch.sensordata[i], ref.sensordata[0])
        np.testing.assert_array_equal(batch.applied[i], ref.applied[0])
        assert ref.warnings[mujoco.mjtWarning.mjWARN_BADQPOS] == (i == 0)
    # the kick at time 30 (step 3), the reset in the next step's mj_step1, halted there
    assert np.abs(batch.physics[0, 3, 1]) > 1e10
    assert batch.physics[0, 4, 0] == 10.0 and np.all(batch.physics[0, 4:] == batch.physics[0, 4])
