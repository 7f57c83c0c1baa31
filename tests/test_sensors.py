"""Sensors as observations, through an observation model: a sensor's value is MuJoCo's at the
measured state (`mj_setState` + `mj_forward`), noise, bias, quantization and dropped readings
are drawn per episode from its state values, so conditions meet the same draws; checked against
plain loops written here with their own generators, on the cart-pole's encoders and on
dm_control's reacher (as shipped) with sensors added in the test."""

from __future__ import annotations

import copy
import dataclasses
import hashlib

import mujoco
import numpy as np
import pytest
import yaml
from conftest import REPO_ROOT
from mujoco import rollout

from mjtrial.sim.closed_loop import Observer, Timing, reference_episode, run_batch
from mjtrial.sim.engine import iter_batches
from mjtrial.sim.physics import FULLPHYSICS
from mjtrial.task import BoundTask, Observation, ProtocolParameter, TaskError, load_task

pytestmark = pytest.mark.end_to_end

CARTPOLE = REPO_ROOT / "tasks" / "cartpole_latency" / "task.py"
REACHER = REPO_ROOT / "tasks" / "reacher_goal" / "task.py"
ERRORS = ("encoder_noise", "encoder_bias", "encoder_quantum", "encoder_dropout")
THRESHOLDS = {"fall_angle": 0.5}


def _with(task, *, observations, protocol=()):
    """The task with these observations declared (the policy reads the same names)."""
    return dataclasses.replace(
        task,
        observations=(*observations, *task.observations[len(observations) :]),
        protocol_parameters=(*task.protocol_parameters, *protocol),
    )


def _encoder_task(**errors):
    """The cart-pole reading its model's encoder sensors, through the observation model."""
    task = load_task(CARTPOLE)
    protocol = tuple(ProtocolParameter(name, "", 0.0) for name in ERRORS)
    roles = dict(zip(("noise", "bias", "quantum", "dropout"), ERRORS, strict=True))
    observations = (
        Observation.sensor("cart_position", "cart_encoder", source="cart encoder", **roles),
        Observation.sensor("pole_angle", "pole_encoder", source="pole encoder", **roles),
    )
    return _with(task, observations=observations, protocol=protocol)


def _states(task, n, seed=5):
    rng = np.random.default_rng(seed)
    return {p.name: rng.uniform(p.low, p.high, n) for p in task.state_parameters}


def _entropy(values_row, name):
    """The documented seed of an episode's draws, written out again."""
    bits = [int(b) for b in np.array(values_row, dtype=np.float64).view(np.uint64)]
    return [*bits, int.from_bytes(hashlib.sha256(name.encode()).digest()[:8], "little")]


def _plain_cartpole(task_module, nominal, episode, params):
    """One noisy-encoder episode as a researcher writes it: the episode's model, a plain
    `mj_step` loop, sensors by `mj_setState` + `mj_forward` at the measured state, then bias,
    noise, rounding and dropped readings from generators of its own."""
    m = copy.copy(nominal)
    pole = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_BODY, "pole")
    m.body_mass[pole] = episode["pole_mass"]
    d = mujoco.MjData(m)
    mujoco.mj_setConst(m, d)
    mujoco.mj_resetData(m, d)
    d.qpos[1] += episode["pole_angle"]
    d.qvel[1] = episode["pole_rate"]
    dt = m.opt.timestep
    per_control, latency = round(params["control_period"] / dt), round(params["latency"] / dt)
    n_controls = round(params["duration"] / params["control_period"])
    push_start = round(episode["push_time"] / dt)
    policy = task_module.policy(m, params)
    policy.reset(1)
    row = list(episode.values())
    names = ("cart_position", "pole_angle")
    z = {
        n: np.random.default_rng([*_entropy(row, n), 0]).standard_normal(n_controls) for n in names
    }
    u = {n: np.random.default_rng([*_entropy(row, n), 1]).random(n_controls) for n in names}
    probe = mujoco.MjData(m)
    state = np.empty(mujoco.mj_stateSize(m, FULLPHYSICS))
    mujoco.mj_getState(m, d, state, FULLPHYSICS)
    history = [state]  # index j: the state after j steps
    delivered = {}
    qpos = []
    for k in range(n_controls):
        mujoco.mj_setState(m, probe, history[max(0, k * per_control - latency)], FULLPHYSICS)
        mujoco.mj_forward(m, probe)
        reading = []
        for column, n in enumerate(names):
            x = probe.sensordata[column] + params["encoder_bias"]
            x = x + params["encoder_noise"] * z[n][k]
            if params["encoder_quantum"]:
                x = np.round(x / params["encoder_quantum"]) * params["encoder_quantum"]
            if k > 0 and u[n][k] < params["encoder_dropout"]:
                x = delivered[n]
            delivered[n] = x
            reading.append(x)
        d.ctrl[:] = policy(np.array([reading]))[0]
        for j in range(k * per_control, (k + 1) * per_control):
            d.xfrc_applied[:] = 0.0
            if push_start <= j < push_start + round(0.1 / dt):
                d.xfrc_applied[pole, 0] = episode["push_force"]
            mujoco.mj_step(m, d)
            after = np.empty_like(state)
            mujoco.mj_getState(m, d, after, FULLPHYSICS)
            history.append(after)
            qpos.append(d.qpos.copy())
    return np.array(qpos)


@pytest.fixture(scope="module")
def cartpole_module():
    import importlib.util

    spec = importlib.util.spec_from_file_location("cartpole_task_module", CARTPOLE)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


@pytest.mark.parametrize(
    "condition",
    [
        {"latency": 0.0, "encoder_noise": 0.01, "encoder_quantum": 0.004, "encoder_dropout": 0.3},
        {"latency": 0.02, "encoder_noise": 0.02, "encoder_bias": 0.01, "encoder_dropout": 0.5},
    ],
)
def test_noisy_encoders_equal_a_plain_loop_with_its_own_generators(cartpole_module, condition):
    task = _encoder_task()
    bound = BoundTask.of(task)
    values = _states(task, 5)
    condition = {**condition, "duration": 1.5}
    [batch] = iter_batches(bound, values, condition, thresholds=THRESHOLDS)
    params = task.parameters(condition)
    for i in range(5):
        episode = {k: float(v[i]) for k, v in values.items()}
        qpos = _plain_cartpole(cartpole_module, bound.model, episode, params)
        np.testing.assert_array_equal(batch.episodes.physics[i, :, 1:3], qpos)
    # the errors do something: the same states without them end elsewhere
    [clean] = iter_batches(bound, values, {"duration": 1.5}, thresholds=THRESHOLDS)
    assert not np.array_equal(clean.episodes.physics, batch.episodes.physics)


def test_without_errors_an_encoder_sensor_is_the_joint_position(cartpole_module):
    """The encoders read through `<sensor>` give the joint-position task's episodes bit for bit
    (a jointpos sensor is qpos), at no latency (the state not yet stepped from) and with it."""
    sensed, plain = BoundTask.of(_encoder_task()), BoundTask.of(load_task(CARTPOLE))
    values = _states(sensed.task, 6, seed=9)
    for latency in (0.0, 0.004):
        condition = {"latency": latency, "duration": 1.5}
        [a] = iter_batches(sensed, values, condition, thresholds=THRESHOLDS)
        [b] = iter_batches(plain, values, condition, thresholds=THRESHOLDS)
        np.testing.assert_array_equal(a.episodes.physics, b.episodes.physics)
        for key in ("success", "peak_angle"):
            np.testing.assert_array_equal(a.outcome[key], b.outcome[key])


def _observer_errors(bound, condition, values, n_controls=50):
    """What the observer adds to a true reading of 0 at each instant: (n, n_controls, 2)."""
    observer = bound.observer(
        ("cart_position", "pole_angle"), values, params=condition, n_controls=n_controls
    )
    n = len(next(iter(values.values())))
    zeros = np.zeros((n, bound.model.nsensordata))
    return np.stack([observer.read(k, None, zeros) for k in range(n_controls)], axis=1)


def test_conditions_meet_the_same_draws():
    """Paired design: the noise of a condition with twice the std is twice the other's, draw
    for draw; a condition differing elsewhere (latency) meets the very same noise; and the draws
    are the episode's own: the same in a batch of one, another for another state."""
    bound = BoundTask.of(_encoder_task())
    values = _states(bound.task, 8)
    small = _observer_errors(bound, {"encoder_noise": 0.01}, values)
    large = _observer_errors(bound, {"encoder_noise": 0.02}, values)
    late = _observer_errors(bound, {"encoder_noise": 0.01, "latency": 0.02}, values)
    np.testing.assert_allclose(large, 2 * small, rtol=1e-12)
    np.testing.assert_array_equal(late, small)
    alone = _observer_errors(bound, {"encoder_noise": 0.01}, {k: v[3:4] for k, v in values.items()})
    np.testing.assert_array_equal(alone[0], small[3])
    assert not np.array_equal(small[0], small[1])
    assert not np.array_equal(small[:, :, 0], small[:, :, 1])  # each observation its own draws
    assert abs(small.std() - 0.01) < 0.002


def test_dropped_readings_hold_the_last_delivered_one():
    bound = BoundTask.of(_encoder_task())
    values = _states(bound.task, 4)
    n_controls = 400
    observer = bound.observer(
        ("pole_angle",), values, params={"encoder_dropout": 0.25}, n_controls=n_controls
    )
    sensors = np.zeros((4, bound.model.nsensordata))
    got = []
    for k in range(n_controls):
        sensors[:, 1] = k  # a reading that changes every instant
        got.append(observer.read(k, None, sensors.copy())[:, 0])
    got = np.array(got).T
    u = np.array(
        [
            np.random.default_rng([*_entropy(row, "pole_angle"), 1]).random(n_controls)
            for row in np.stack([values[p.name] for p in bound.task.state_parameters], 1)
        ]
    )
    expected = np.zeros_like(got)
    for k in range(1, n_controls):
        expected[:, k] = np.where(u[:, k] < 0.25, expected[:, k - 1], k)
    np.testing.assert_array_equal(got, expected)
    assert 0.2 < (np.diff(got, axis=1) == 0).mean() < 0.3


def test_results_do_not_depend_on_the_batch_or_threads():
    bound = BoundTask.of(_encoder_task())
    values = _states(bound.task, 10, seed=2)
    condition = {"duration": 1.5, "encoder_noise": 0.01, "encoder_dropout": 0.2}

    def run(**kwargs):
        batches = list(iter_batches(bound, values, condition, thresholds=THRESHOLDS, **kwargs))
        return np.concatenate([b.episodes.physics for b in batches])

    whole = run()
    np.testing.assert_array_equal(run(batch_size=3), whole)
    np.testing.assert_array_equal(run(batch_size=4, nthread=2), whole)


POSITION_AND_VELOCITY = 7  # the added sensors' columns before the accelerometer's


@pytest.fixture(scope="module")
def reacher_with_sensors():
    """dm_control's reacher as shipped, with sensors added here (MjSpec): the fingertip's
    position, the joints' angles and rates, and an accelerometer (refused as an observation)."""
    task = load_task(REACHER)
    spec = mujoco.MjSpec.from_file(str(task.model))
    spec.body("finger").add_site(name="fingertip")
    joint, site = mujoco.mjtObj.mjOBJ_JOINT, mujoco.mjtObj.mjOBJ_SITE
    for name, kind, objtype, target in (
        ("tip", mujoco.mjtSensor.mjSENS_FRAMEPOS, site, "fingertip"),
        ("shoulder_encoder", mujoco.mjtSensor.mjSENS_JOINTPOS, joint, "shoulder"),
        ("wrist_encoder", mujoco.mjtSensor.mjSENS_JOINTPOS, joint, "wrist"),
        ("shoulder_rate", mujoco.mjtSensor.mjSENS_JOINTVEL, joint, "shoulder"),
        ("wrist_rate", mujoco.mjtSensor.mjSENS_JOINTVEL, joint, "wrist"),
        ("accelerometer", mujoco.mjtSensor.mjSENS_ACCELEROMETER, site, "fingertip"),
    ):
        spec.add_sensor(name=name, type=kind, objtype=objtype, objname=target)
    return task, spec.compile()


class Recorder:
    """A constant torque on both joints; keeps every observation it is given."""

    def __init__(self):
        self.seen = []

    def reset(self, n):
        pass

    def __call__(self, obs):
        self.seen.append(obs.copy())
        return np.tile([0.3, -0.5], (len(obs), 1))


@pytest.mark.parametrize("latency_steps", [0, 2])
def test_a_sensor_is_what_mj_forward_gives_at_the_measured_state(
    reacher_with_sensors, latency_steps
):
    """The engine gives the policy, at every instant, the sensors `mj_setState` + `mj_forward`
    compute at the measured state; what `mj_step` records with step j + 1 is those of the state
    after step j, before it integrates."""
    task, model = reacher_with_sensors
    bound = BoundTask.of(task, model)
    values = _states(task, 4)
    scratch = mujoco.MjData(model)
    episodes = [
        bound.episode({k: v[i] for k, v in values.items()}, scratch=scratch) for i in range(4)
    ]
    models, initial = [m for m, _ in episodes], np.stack([s for _, s in episodes])
    policy, timing = Recorder(), Timing(1, 30, latency_steps)
    observer = Observer(lambda k, states, sensors: sensors, sensed=True)
    with rollout.Rollout(nthread=0) as runner:
        batch = run_batch(
            models, initial, policy, observer, timing, runner=runner, datas=[scratch], check=False
        )
    probe = mujoco.MjData(model)
    states = np.concatenate([initial[:, None], batch.physics], axis=1)  # index j: after j steps
    cols = slice(0, POSITION_AND_VELOCITY)
    for i in range(4):
        for j in range(30):
            mujoco.mj_setState(models[i], probe, states[i, j], FULLPHYSICS)
            mujoco.mj_forward(models[i], probe)
            np.testing.assert_array_equal(batch.sensordata[i, j, cols], probe.sensordata[cols])
            k = j + latency_steps  # the instant that observes state j
            if k < 30:
                np.testing.assert_array_equal(policy.seen[k][i, cols], probe.sensordata[cols])
    assert np.ptp(np.stack(policy.seen)[:, :, :3]) > 0.01  # the fingertip moves


def test_the_reacher_reading_noisy_sensors_matches_the_per_episode_loop(reacher_with_sensors):
    """On a third-party model: encoders and a goal seen by a camera, through the observation
    model; the engine equals, bit for bit, the per-episode loop it is checked against."""
    task, model = reacher_with_sensors
    protocol = tuple(
        ProtocolParameter(name, "", 0.0)
        for name in ("encoder_noise", "encoder_quantum", "goal_noise")
    )
    encoder = {"source": "joint encoder", "noise": "encoder_noise", "quantum": "encoder_quantum"}
    observations = (
        Observation.sensor("shoulder_angle", "shoulder_encoder", **encoder),
        Observation.sensor("wrist_angle", "wrist_encoder", **encoder),
        Observation.episode_value("goal_x", "goal_x", source="camera", noise="goal_noise"),
        Observation.episode_value("goal_y", "goal_y", source="camera", noise="goal_noise"),
    )
    bound = BoundTask.of(_with(task, observations=observations, protocol=protocol), model)
    task = bound.task
    values = _states(task, 4, seed=8)
    params = task.parameters(
        {
            "kp": 1.0,
            "duration": 0.6,
            "encoder_noise": 0.01,
            "encoder_quantum": 0.002,
            "goal_noise": 0.02,
        }
    )
    [batch] = iter_batches(bound, values, params, thresholds={})
    timing = task.controller.timing(model, params)
    scratch = mujoco.MjData(model)
    for i in range(4):
        m, state = bound.episode({k: float(v[i]) for k, v in values.items()}, scratch=scratch)
        observer = bound.observer(
            task.controller.observations,
            {k: v[i : i + 1] for k, v in values.items()},
            params=params,
            n_controls=timing.n_controls,
        )
        policy = task.controller.policy(model, params)
        ref = reference_episode(m, state, policy, observer, timing)
        np.testing.assert_array_equal(batch.episodes.physics[i], ref.physics[0])
    # the errors do something
    [clean] = iter_batches(
        bound, values, task.parameters({"kp": 1.0, "duration": 0.6}), thresholds={}
    )
    assert not np.array_equal(clean.episodes.physics, batch.episodes.physics)


@pytest.mark.parametrize(
    ("change", "message"),
    [
        (
            {"sensor": "cart_encoderr"},
            r"observation 'cart_position': expected a sensor named 'cart_encoderr' in the model",
        ),
        (
            {"noise": "encoder_nois"},
            r"observation 'cart_position': noise: expected one of the protocol parameters "
            r"\[.*\], got 'encoder_nois'",
        ),
    ],
)
def test_a_sensor_observation_naming_nothing_is_one_line(change, message):
    task = _encoder_task()
    arguments = {"sensor": "cart_encoder", "noise": "encoder_noise"} | change
    bad = Observation.sensor(
        "cart_position", arguments.pop("sensor"), source="encoder", **arguments
    )
    with pytest.raises(TaskError, match=message) as err:
        BoundTask.of(_with(task, observations=(bad,)))
    assert "\n" not in str(err.value) and str(CARTPOLE) in str(err.value)


def test_an_acceleration_sensor_is_refused(reacher_with_sensors):
    task, model = reacher_with_sensors
    bad = Observation.sensor("shoulder_angle", "accelerometer", source="IMU")
    with pytest.raises(
        TaskError, match=r"sensor 'accelerometer' \(accelerometer\) is computed from accelerations"
    ):
        BoundTask.of(_with(task, observations=(bad,)), model)


@pytest.mark.parametrize(
    ("condition", "message"),
    [
        ({"encoder_noise": -0.1}, r"noise parameter 'encoder_noise' is -0.1; expected >= 0"),
        (
            {"encoder_dropout": 1.0},
            r"dropout parameter 'encoder_dropout' is 1; expected a probability in \[0, 1\)",
        ),
        (
            {"encoder_dropout": -0.2},
            r"dropout parameter 'encoder_dropout' is -0.2; expected a probability",
        ),
        (
            {"encoder_quantum": -1e-3},
            r"quantum parameter 'encoder_quantum' is -0.001; expected >= 0",
        ),
    ],
)
def test_a_bad_observation_model_value_is_one_line_before_any_episode(condition, message):
    bound = BoundTask.of(_encoder_task())
    values = _states(bound.task, 2)
    with pytest.raises(TaskError, match=message) as err:
        next(iter_batches(bound, values, {"duration": 1.5, **condition}, thresholds=THRESHOLDS))
    assert str(err.value).startswith(f"{CARTPOLE}: observation 'cart_position': ")
    assert "\n" not in str(err.value)


PIPELINE_CONFIG = "config/cartpole_sensors.yaml"
PIPELINE_RESULTS = "results/cartpole_sensors"


@pytest.fixture(scope="module")
def noisy_run(tmp_path_factory):
    """The cart-pole experiment, its task reading the encoder sensors through an observation
    model, on 16 states: with exact encoders and with noise and dropped readings."""
    from conftest import copy_workflow, run_snakemake

    workdir = tmp_path_factory.mktemp("sensors")
    copy_workflow(workdir)
    task = workdir / "tasks" / "cartpole_latency" / "task.py"
    text = task.read_text()
    for name, joint in (("cart_position", "CART"), ("pole_angle", "POLE")):
        old = f'Observation.joint_position("{name}", {joint}, source='
        assert old in text
        sensor = "cart_encoder" if joint == "CART" else "pole_encoder"
        errors = 'noise="encoder_noise", dropout="encoder_dropout", source='
        text = text.replace(old, f'Observation.sensor("{name}", "{sensor}", {errors}')
    text = text.replace(
        "    protocol_parameters=(\n",
        "    protocol_parameters=(\n"
        '        ProtocolParameter("encoder_noise", "rad", 0.0, minimum=0.0),\n'
        '        ProtocolParameter("encoder_dropout", "", 0.0, minimum=0.0, maximum=0.9),\n',
        1,
    )
    task.write_text(text)
    config = yaml.safe_load((REPO_ROOT / "config" / "cartpole_latency.yaml").read_text())
    config |= {
        "experiment": "cartpole_sensors",
        "conditions": {
            "exact": {"latency": 0.0},
            "noisy": {"latency": 0.0, "encoder_noise": 0.01, "encoder_dropout": 0.3},
        },
    }
    config["states"]["n"] = 16
    config["rollout"]["shard_size"] = 16
    config["recording"]["episodes"] = "none"
    config["design"]["falsifier"] |= {"treatment": "exact", "baseline": "noisy"}
    config["sweep"]["base"] = "noisy"
    (workdir / PIPELINE_CONFIG).write_text(yaml.safe_dump(config, sort_keys=False))
    tables = [f"{PIPELINE_RESULTS}/rollouts/{c}.parquet" for c in ("exact", "noisy")]
    run_snakemake(workdir, *tables, "--configfile", PIPELINE_CONFIG)
    return workdir


def test_noisy_episodes_re_simulated_alone_as_verify_does_equal_their_rows(noisy_run):
    """Verify re-simulates a sample of each table's episodes, each alone, from the states table
    (`Recompute.resimulated`): the same draws, the same rows. Done here with the functions it
    calls (a whole run's verify needs the report and the crate besides)."""
    import pyarrow.parquet as pq

    from mjtrial.files.layout import Layout
    from mjtrial.stages.rollout import (
        condition_batches,
        condition_task,
        read_state_values,
        rollout_columns,
    )
    from mjtrial.stages.stamping import config_slice
    from mjtrial.verify import load_checked_config

    config = load_checked_config(noisy_run / PIPELINE_CONFIG, repo_root=noisy_run)
    layout = Layout.of(config["experiment"], base=noisy_run / "results")
    tables = {
        c: pq.read_table(layout.rollout_table(c, "nominal")).to_pylist() for c in ("exact", "noisy")
    }
    assert [r["peak_angle"] for r in tables["noisy"]] != [r["peak_angle"] for r in tables["exact"]]
    slice_ = config_slice("rollout", config, condition="noisy")
    bound = condition_task(slice_, noisy_run / config["model"], repo_root=noisy_run)
    every = read_state_values(layout.states, bound.task)
    ids = [2, 11, 15]
    columns = rollout_columns(bound.task)
    batches = condition_batches(
        bound, slice_, {k: v[ids] for k, v in every.items()}, nthread=1, batch_size=1
    )
    for state_id, batch in zip(ids, batches, strict=True):
        alone = {c: batch.outcome[c][0] for c in columns[1:]}
        alone = {c: v.item() if hasattr(v, "item") else v for c, v in alone.items()}
        assert alone == {c: tables["noisy"][state_id][c] for c in alone}


def test_the_manifest_and_report_say_what_errors_an_observation_has(noisy_run):
    from mjtrial.report.setup import _task_lines
    from mjtrial.stages.manifest import task_record

    record = task_record({"task": "tasks/cartpole_latency/task.py"}, repo_root=noisy_run)
    errors = {"noise": "encoder_noise", "dropout": "encoder_dropout"}
    assert record["observation_errors"] == {"cart_position": errors, "pole_angle": errors}
    [read] = [line for line in _task_lines(record) if "policy reads" in line]
    assert "pole_angle (pole encoder; noise: `encoder_noise`; dropout: `encoder_dropout`)" in read
    # a task without errors records nothing new (its manifest stays as it was)
    assert "observation_errors" not in task_record({"task": str(CARTPOLE)})


def test_a_sensor_without_a_source_is_privileged():
    from mjtrial.task.checks import check_observations

    task = _encoder_task()
    hidden = Observation.sensor("pole_angle", "pole_encoder", source=None)
    task = dataclasses.replace(task, observations=(task.observations[0], hidden))
    with pytest.raises(TaskError, match="the policy reads 'pole_angle', a privileged observation"):
        check_observations(task, {})
    assert check_observations(task, {"pole_angle": "an upper bound"}) == {
        "pole_angle": "an upper bound"
    }
