"""The closed-loop engine: equal to a plain mj_step loop bit for bit, independent of batch size
and thread count; LQR gains against an analytic linearization; policies checked for batch
independence."""

from __future__ import annotations

import copy

import mujoco
import numpy as np
import pytest
import scipy.linalg
from conftest import REPO_ROOT
from mujoco import rollout

from mjtrial.sim.closed_loop import (
    PolicyError,
    Pushes,
    Timing,
    check_batch_independence,
    check_replayed,
    reference_episode,
    run_batch,
)
from mjtrial.sim.controllers import EncoderFeedback, StateFeedback, lqr_gain
from mjtrial.sim.physics import FULLPHYSICS

CARTPOLE = REPO_ROOT / "tasks" / "cartpole_latency" / "cartpole.xml"
STEPS_PER_CONTROL = 5
NOMINAL = mujoco.MjModel.from_xml_path(str(CARTPOLE))  # the LQR is designed on it


@pytest.fixture(scope="module")
def cartpole():
    return NOMINAL


def _episodes(model, n, seed=3):
    """n episodes: pole mass, initial angle and rate, a push on the pole."""
    rng = np.random.default_rng(seed)
    pole = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_BODY, "pole")
    data = mujoco.MjData(model)
    models, initial = [], []
    for mass, angle, rate in zip(
        rng.uniform(0.05, 0.3, n), rng.uniform(-0.1, 0.1, n), rng.uniform(-0.5, 0.5, n), strict=True
    ):
        m = copy.copy(model)
        m.body_mass[pole] = mass
        mujoco.mj_setConst(m, data)
        mujoco.mj_resetData(m, data)
        data.qpos[1], data.qvel[1] = angle, rate
        state = np.empty(mujoco.mj_stateSize(m, FULLPHYSICS))
        mujoco.mj_getState(m, data, state, FULLPHYSICS)
        models.append(m)
        initial.append(state)
    start = rng.integers(200, 400, n)
    wrench = np.zeros((n, 6))
    wrench[:, 0] = rng.uniform(-6, 6, n)
    return models, np.stack(initial), Pushes(pole, start, start + 50, wrench)


def _policy(model):
    gain = lqr_gain(
        model,
        q=np.diag([10.0, 50.0, 1.0, 1.0]),
        r=np.eye(1) * 0.02,
        steps_per_control=STEPS_PER_CONTROL,
    )
    period = STEPS_PER_CONTROL * model.opt.timestep
    return EncoderFeedback(gain, period=period, ctrl_range=model.actuator_ctrlrange)


@pytest.mark.parametrize("controller", ["encoder feedback", "state feedback"])
def test_a_controllers_episode_alone_is_a_reset_and_a_call_per_instant_bit_for_bit(controller):
    """`alone`, the replay check's path for the built-in controllers (`check_replayed`), against
    the plain per-call path (what the reference episode and verify's re-simulation run): the
    same bits, actions clipped at both ends included."""
    encoder = _policy(NOMINAL)
    if controller == "encoder feedback":
        policy = encoder
        # a slow drift, then two jumps whose finite-difference velocities saturate the motor
        observations = np.cumsum(np.random.default_rng(5).normal(scale=1e-3, size=(60, 2)), 0)
        observations[20:, 1] += 0.5
        observations[40:, 1] -= 1.0
    else:
        policy = StateFeedback(encoder.gain[:, :4], ctrl_range=NOMINAL.actuator_ctrlrange)
        observations = np.random.default_rng(5).normal(scale=0.05, size=(60, 4))
        observations[[10, 30], 1] = [0.9, -0.9]  # angles that saturate the motor
    policy.reset(1)
    expected = np.concatenate([policy(observations[k : k + 1]) for k in range(60)])
    got = policy.alone(observations)
    np.testing.assert_array_equal(got, expected)
    low, high = NOMINAL.actuator_ctrlrange[0]
    assert got.min() == low and got.max() == high
    assert low < np.median(got) < high


def encoders(states):
    return states[:, 1:3]


def _run(models, initial, pushes, timing, *, nthread, batch_size):
    out = []
    with rollout.Rollout(nthread=nthread) as runner:
        datas = [mujoco.MjData(models[0]) for _ in range(max(1, nthread))]
        for start in range(0, len(models), batch_size):
            rows = slice(start, start + batch_size)
            out.append(
                run_batch(
                    models[rows],
                    initial[rows],
                    _policy(NOMINAL),
                    encoders,
                    timing,
                    runner=runner,
                    datas=datas,
                    pushes=pushes.rows(rows),
                )
            )
    return (
        np.concatenate([b.physics for b in out]),
        np.concatenate([b.ctrl for b in out]),
        np.concatenate([b.sensordata for b in out]),
    )


@pytest.mark.parametrize("latency_steps", [0, 3, 10])
def test_engine_equals_plain_mj_step_loop(cartpole, latency_steps):
    models, initial, pushes = _episodes(cartpole, 6)
    timing = Timing(STEPS_PER_CONTROL, 150, latency_steps)
    physics, ctrl, sensors = _run(models, initial, pushes, timing, nthread=0, batch_size=6)
    for i in range(6):
        ref = reference_episode(
            models[i], initial[i], _policy(cartpole), encoders, timing, pushes=pushes.rows([i])
        )
        np.testing.assert_array_equal(physics[i], ref.physics[0])
        np.testing.assert_array_equal(sensors[i], ref.sensordata[0])
        np.testing.assert_array_equal(ctrl[i], ref.ctrl[0])
    # the push and the latency do something: episodes differ from one another and move
    assert np.ptp(physics[:, -1, 1]) > 0.01


def test_results_do_not_depend_on_batch_size_or_threads(cartpole):
    models, initial, pushes = _episodes(cartpole, 10)
    timing = Timing(STEPS_PER_CONTROL, 100, 10)
    physics, ctrl, sensors = _run(models, initial, pushes, timing, nthread=0, batch_size=10)
    for nthread, batch_size in [(0, 1), (0, 3), (2, 4), (2, 10)]:
        p, c, sd = _run(models, initial, pushes, timing, nthread=nthread, batch_size=batch_size)
        np.testing.assert_array_equal(p, physics)
        np.testing.assert_array_equal(sd, sensors)
        np.testing.assert_array_equal(c, ctrl)


def test_latency_delays_the_observation(cartpole):
    """With latency L, the control at instant k equals what the policy gives for the state of
    step k*S - L: checked against the recorded states, independently of the engine's index."""
    models, initial, pushes = _episodes(cartpole, 2)
    timing = Timing(STEPS_PER_CONTROL, 40, 7)
    physics, ctrl, _ = _run(models, initial, pushes, timing, nthread=0, batch_size=2)
    policy = _policy(cartpole)
    policy.reset(2)
    states = np.concatenate([initial[:, None], physics], axis=1)  # row j: after step j
    for k in range(40):
        j = max(0, k * STEPS_PER_CONTROL - 7)
        np.testing.assert_array_equal(policy(states[:, j, 1:3]), ctrl[:, k])


def test_pushes_act_only_in_their_window(cartpole):
    pole = mujoco.mj_name2id(cartpole, mujoco.mjtObj.mjOBJ_BODY, "pole")
    pushes = Pushes(pole, np.array([3]), np.array([6]), np.array([[1.0, 0, 0, 0, 0, 2.0]]))
    xfrc = pushes.xfrc(cartpole.nbody, 0, 10).reshape(1, 10, cartpole.nbody, 6)
    on = np.zeros(10, bool)
    on[3:6] = True
    assert (xfrc[0, on, pole, 0] == 1.0).all() and (xfrc[0, on, pole, 5] == 2.0).all()
    assert not xfrc[0, ~on].any() and not np.delete(xfrc[0], pole, axis=1).any()


def test_lqr_gain_matches_an_analytic_double_integrator():
    """A 2 kg block on a frictionless slide, semi-implicit Euler: v' = v + h u / m,
    x' = x + h v'. Its exact discrete (A, B) give the reference gain through scipy."""
    h, mass = 0.01, 2.0
    model = mujoco.MjModel.from_xml_string(
        f"""<mujoco><option timestep="{h}" integrator="Euler" gravity="0 0 0"/>
        <worldbody><body><joint name="x" type="slide" axis="1 0 0"/>
        <geom type="box" size=".1 .1 .1" mass="{mass}"/></body></worldbody>
        <actuator><motor joint="x"/></actuator></mujoco>"""
    )
    a = np.array([[1.0, h], [0.0, 1.0]])
    b = np.array([[h * h / mass], [h / mass]])
    q, r = np.diag([3.0, 0.5]), np.eye(1) * 0.1
    for s in (1, 4):
        a_s = np.linalg.matrix_power(a, s)
        b_s = sum(np.linalg.matrix_power(a, i) @ b for i in range(s))
        p = scipy.linalg.solve_discrete_are(a_s, b_s, q, r)
        expected = np.linalg.solve(r + b_s.T @ p @ b_s, b_s.T @ p @ a_s)
        got = lqr_gain(model, q=q, r=r, steps_per_control=s)
        np.testing.assert_allclose(got, expected, rtol=1e-6)


def test_lqr_balances_the_cartpole(cartpole):
    """The closed loop of the nominal cart-pole is stable: a small tilt decays."""
    models, initial, _ = _episodes(cartpole, 1)
    initial = initial.copy()
    initial[0, 2], initial[0, 4] = 0.05, 0.0  # pole angle, rate
    timing = Timing(STEPS_PER_CONTROL, 300)
    no_push = Pushes(1, np.array([0]), np.array([0]), np.zeros((1, 6)))
    physics, _, _ = _run([cartpole], initial, no_push, timing, nthread=0, batch_size=1)
    assert abs(physics[0, -1, 2]) < 1e-3 and abs(physics[0, -1, 1]) < 0.05


class _BatchMean:
    """A policy that (wrongly) mixes rows: each control depends on the batch."""

    def reset(self, n_episodes):
        pass

    def __call__(self, observations):
        return observations[:, :1] - observations[:, :1].mean()


def test_batch_dependent_policy_is_refused(cartpole):
    obs = np.random.default_rng(0).normal(size=(5, 2))
    check_batch_independence(_policy(cartpole), obs)
    with pytest.raises(PolicyError, match="row 0 alone gives other controls"):
        check_batch_independence(_BatchMean(), obs)


@pytest.mark.parametrize(
    ("bad", "message"),
    [
        (lambda obs: np.zeros((len(obs), 2)), r"expected controls of shape \(3, 1\), got \(3, 2\)"),
        (lambda obs: np.full((len(obs), 1), np.nan), "non-finite controls for 3 episode"),
    ],
)
def test_bad_controls_are_named(cartpole, bad, message):
    class Bad:
        def reset(self, n_episodes):
            pass

        def __call__(self, observations):
            return bad(observations)

    models, initial, pushes = _episodes(cartpole, 3)
    with rollout.Rollout(nthread=0) as runner, pytest.raises(PolicyError, match=message):
        run_batch(
            models,
            initial,
            Bad(),
            encoders,
            Timing(STEPS_PER_CONTROL, 5),
            runner=runner,
            datas=[mujoco.MjData(cartpole)],
            pushes=pushes,
        )


class _FirstRowNudged:
    """Depends on a row's position: the first row of any batch gets 1e-9 N more."""

    def reset(self, n_episodes):
        pass

    def __call__(self, observations):
        controls = -observations[:, :1].copy()
        controls[0] += 1e-9
        return controls


def test_replaying_a_batch_in_other_batches_names_a_row_that_moved():
    """Issue 26 case 1: replayed alone, row 1 comes first (row 0 was first in the batch too)."""
    observations = np.random.default_rng(1).normal(size=(6, 3, 2))
    policy = _FirstRowNudged()
    controls = np.stack([policy(observations[:, k]) for k in range(3)], axis=1)
    with pytest.raises(
        PolicyError,
        match=r"batch dependence: episode row 1 of a batch of 6 gets other controls at control "
        r"instant 0 when it runs alone \(largest difference 1e-09\)",
    ):
        check_replayed(policy, observations, controls)
    honest = _policy(NOMINAL)  # with memory: velocities by finite differences
    honest.reset(6)
    controls = np.stack([honest(observations[:, k]) for k in range(3)], axis=1)
    check_replayed(honest, observations, controls)
