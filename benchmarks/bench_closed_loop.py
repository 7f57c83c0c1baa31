"""Benchmark: the batched closed-loop engine against the per-episode loop a researcher writes.

The baseline is the plain loop: one `MjData` per episode, the same policy called once per
control step on that episode's observation, `mj_step` in a Python loop in between, the push
set per step, success checked at every step of the last second, nothing recorded.
The engine runs the same episodes in lockstep batches (`mjtrial.sim.closed_loop.run_batch`) and
records every physics step's state besides. Episodes: the cart-pole of `tasks/cartpole_latency/`,
2.5 s, a 10 ms control period (5 steps of 2 ms), 20 ms of sensing latency, a push on the pole.

Two ways to sense: the encoders as the joints' positions in the state (`--sensing state`), or
as the model's encoder `<sensor>`s through an observation model (`--sensing sensors`: noise,
a bias, quantization and dropped readings, `mjtrial.task.observation_model`). There the engine
runs what the pipeline runs per batch (`BoundTask.observer` of the cart-pole task with sensor
observations, then `run_batch`), and the loop reads `d.sensordata` where `mj_step` leaves the
measured state's (the first step of each control period computes the sensors of the state it
starts from), draws each episode's noise from its own generators once, and applies the errors
to its two readings at each control instant.

    python benchmarks/bench_closed_loop.py                 # 400 episodes, 5 repeats, both
    python benchmarks/bench_closed_loop.py --episodes 100 --repeats 3 --sensing sensors

It prints episodes per second of each, and the engine's speed over the loop's on 1 and 2
threads: the median of the paired ratios over repeats (each repeat runs the loop and the engine
back to back, in an order that flips every repeat), with their range.
"""

from __future__ import annotations

import argparse
import collections
import copy
import dataclasses
import hashlib

import mujoco
import numpy as np
from alternating import print_rates, time_alternating
from mujoco import rollout

from mjtrial import REPO_ROOT
from mjtrial.sim.closed_loop import Pushes, Timing, run_batch
from mjtrial.sim.controllers import EncoderFeedback, lqr_gain
from mjtrial.sim.physics import FULLPHYSICS
from mjtrial.task import BoundTask, Observation, ProtocolParameter, load_task

MODEL = REPO_ROOT / "tasks" / "cartpole_latency" / "cartpole.xml"
TASK = REPO_ROOT / "tasks" / "cartpole_latency" / "task.py"
ENCODERS = ("cart_encoder", "pole_encoder")  # the model's sensors: cart position, pole angle
# The observation model of `--sensing sensors`: each error's protocol parameter and value.
ERRORS = {"noise": 0.002, "bias": 0.001, "quantum": 0.0005, "dropout": 0.1}
STEPS_PER_CONTROL = 5
DURATION = 2.5  # s
LATENCY = 0.02  # s
BATCH_SIZE = 200


def episodes(model: mujoco.MjModel, n: int, seed: int = 0):
    """Per-episode models (pole mass), initial states (pole angle, rate) and pushes."""
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
    start = rng.integers(250, 500, n)
    wrench = np.zeros((n, 6))
    wrench[:, 0] = rng.uniform(-6, 6, n)
    return models, np.stack(initial), Pushes(pole, start, start + 50, wrench)


def state_values(models, initial, pushes, nominal) -> dict[str, np.ndarray]:
    """The episodes' values of the cart-pole task's state parameters (the draws' seed)."""
    pole = pushes.body
    return {
        "pole_angle": initial[:, 1 + 1],  # after time: qpos[0], qpos[1]
        "pole_rate": initial[:, 1 + nominal.nq + 1],
        "pole_mass": np.array([m.body_mass[pole] for m in models]),
        "push_force": pushes.wrench[:, 0],
        "push_time": pushes.start * nominal.opt.timestep,
    }


def sensing_task() -> BoundTask:
    """The cart-pole task reading its encoder sensors through the observation model."""
    task = load_task(TASK)
    observations = tuple(
        Observation.sensor(name, sensor, source="encoder", **{r: r for r in ERRORS})
        for name, sensor in zip(("cart_position", "pole_angle"), ENCODERS, strict=True)
    )
    return BoundTask.of(
        dataclasses.replace(
            task,
            observations=(*observations, *task.observations[2:]),
            protocol_parameters=(
                *task.protocol_parameters,
                *(ProtocolParameter(r, "", 0.0) for r in ERRORS),
            ),
        )
    )


def _seed(values: list[float], name: str) -> list[int]:
    bits = np.array(values, dtype=np.float64).view(np.uint64)
    return [*map(int, bits), int.from_bytes(hashlib.sha256(name.encode()).digest()[:8], "little")]


def plain_loop_sensors(nominal, models, initial, pushes, timing, values) -> int:
    """The per-episode loop reading the encoder sensors through the same observation model;
    returns the number of successes."""
    policy = policy_for(nominal)
    judged_from = timing.n_steps - round(1.0 / nominal.opt.timestep)
    delay = timing.latency_steps // STEPS_PER_CONTROL  # in control periods (>= 1 here)
    names = ("cart_position", "pole_angle")
    columns = [nominal.sensor(s).adr[0] for s in ENCODERS]
    noise, bias, quantum, dropout = (ERRORS[r] for r in ("noise", "bias", "quantum", "dropout"))
    rows = np.stack(list(values.values()), axis=1)
    successes = 0
    for i, m in enumerate(models):
        d = mujoco.MjData(m)
        mujoco.mj_setState(m, d, initial[i], FULLPHYSICS)
        mujoco.mj_forward(m, d)
        seeds = [_seed(rows[i], name) for name in names]
        z = np.stack(
            [np.random.default_rng([*s, 0]).standard_normal(timing.n_controls) for s in seeds], 1
        )
        lost = np.stack(
            [np.random.default_rng([*s, 1]).random(timing.n_controls) for s in seeds], 1
        )
        lost = lost < dropout
        policy.reset(1)
        # seen[b]: the sensors of the state each control period b starts from
        seen = [d.sensordata[columns].copy()]
        delivered = None
        upright = True
        for k in range(timing.n_controls):
            reading = seen[max(0, k - delay)] + bias + noise * z[k]
            reading = np.round(reading / quantum) * quantum
            if delivered is not None:
                reading = np.where(lost[k], delivered, reading)
            delivered = reading
            d.ctrl[:] = policy(reading[None])[0]
            for j in range(k * STEPS_PER_CONTROL, (k + 1) * STEPS_PER_CONTROL):
                pushed = pushes.start[i] <= j < pushes.stop[i]
                d.xfrc_applied[pushes.body] = pushes.wrench[i] if pushed else 0.0
                mujoco.mj_step(m, d)
                if j == k * STEPS_PER_CONTROL and k > 0:
                    seen.append(d.sensordata[columns].copy())
                if j >= judged_from:
                    upright &= abs(d.qpos[1]) < 0.25 and abs(d.qpos[0]) < 1.0
        successes += upright
    return successes


def policy_for(model: mujoco.MjModel) -> EncoderFeedback:
    gain = lqr_gain(
        model, q=np.diag([10.0, 50.0, 1.0, 1.0]), r=np.eye(1) * 0.02, steps_per_control=5
    )
    period = STEPS_PER_CONTROL * model.opt.timestep
    return EncoderFeedback(gain, period=period, ctrl_range=model.actuator_ctrlrange)


def plain_loop(nominal, models, initial, pushes, timing) -> int:
    """The per-episode loop; returns the number of successes."""
    policy = policy_for(nominal)
    judged_from = timing.n_steps - round(1.0 / nominal.opt.timestep)  # the last second
    delay = timing.latency_steps // STEPS_PER_CONTROL  # in control periods
    successes = 0
    for i, m in enumerate(models):
        d = mujoco.MjData(m)
        mujoco.mj_setState(m, d, initial[i], FULLPHYSICS)
        policy.reset(1)
        measured = collections.deque([d.qpos.copy()] * (delay + 1), maxlen=delay + 1)
        upright = True
        for k in range(timing.n_controls):
            d.ctrl[:] = policy(measured[0][None])[0]
            for j in range(k * STEPS_PER_CONTROL, (k + 1) * STEPS_PER_CONTROL):
                pushed = pushes.start[i] <= j < pushes.stop[i]
                d.xfrc_applied[pushes.body] = pushes.wrench[i] if pushed else 0.0
                mujoco.mj_step(m, d)
                if j >= judged_from:
                    upright &= abs(d.qpos[1]) < 0.25 and abs(d.qpos[0]) < 1.0
            measured.append(d.qpos.copy())
        successes += upright
    return successes


def engine(nominal, models, initial, pushes, timing, nthread, sensing=None) -> int:
    """The engine over the same episodes, in batches; returns the number of successes.
    `sensing`: (the task reading sensors, the episodes' state values), or None: the state."""
    last_second = round(1.0 / nominal.opt.timestep)
    successes = 0
    policy = policy_for(nominal)  # once, as the pipeline builds it once per condition
    with rollout.Rollout(nthread=nthread) as runner:
        datas = [mujoco.MjData(nominal) for _ in range(max(1, nthread))]
        for start in range(0, len(models), BATCH_SIZE):
            rows = slice(start, start + BATCH_SIZE)
            if sensing is None:
                observe = lambda states: states[:, 1:3]  # noqa: E731
            else:
                bound, values = sensing
                observe = bound.observer(
                    bound.task.controller.observations,
                    {k: v[rows] for k, v in values.items()},
                    params=ERRORS,
                    n_controls=timing.n_controls,
                )
            batch = run_batch(
                models[rows],
                initial[rows],
                policy,
                observe,
                timing,
                runner=runner,
                datas=datas,
                pushes=pushes.rows(rows),
            )
            tail = batch.physics[:, -last_second:]
            successes += int(
                ((np.abs(tail[:, :, 2]) < 0.25) & (np.abs(tail[:, :, 1]) < 1)).all(1).sum()
            )
    return successes


def compare(nominal, models, initial, pushes, timing, repeats, sensing) -> None:
    """Time the loop and the engine on 1 and 2 threads, alternating, and print the ratios."""
    n = len(models)
    if sensing is None:
        loop = lambda: plain_loop(nominal, models, initial, pushes, timing)  # noqa: E731
    else:
        values = sensing[1]
        loop = lambda: plain_loop_sensors(nominal, models, initial, pushes, timing, values)  # noqa: E731
    outcome, seconds, ratios = time_alternating(
        loop,
        lambda t: engine(nominal, models, initial, pushes, timing, t if t > 1 else 0, sensing),
        repeats,
    )
    print(f"successes: loop {outcome['loop']}, engine {outcome['engine']} (of {n}; must be equal)")
    print_rates(n, seconds, ratios)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--episodes", type=int, default=400)
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--sensing", choices=("state", "sensors", "both"), default="both")
    args = parser.parse_args()
    nominal = mujoco.MjModel.from_xml_path(str(MODEL))
    dt = nominal.opt.timestep
    timing = Timing(
        STEPS_PER_CONTROL,
        round(DURATION / (STEPS_PER_CONTROL * dt)),
        round(LATENCY / dt),
    )
    models, initial, pushes = episodes(nominal, args.episodes)
    print(
        f"{args.episodes} cart-pole episodes of {DURATION} s, control every "
        f"{STEPS_PER_CONTROL * dt * 1e3:.0f} ms,"
        f" latency {LATENCY * 1e3:.0f} ms; engine batches of {BATCH_SIZE}; {args.repeats} repeats"
    )
    if args.sensing in ("state", "both"):
        print("\nencoders read from the state:")
        compare(nominal, models, initial, pushes, timing, args.repeats, None)
    if args.sensing in ("sensors", "both"):
        errors = ", ".join(f"{k} {v:g}" for k, v in ERRORS.items())
        print(f"\nencoder sensors through an observation model ({errors}):")
        sensing = (sensing_task(), state_values(models, initial, pushes, nominal))
        compare(nominal, models, initial, pushes, timing, args.repeats, sensing)


if __name__ == "__main__":
    main()
