"""Closed-loop episodes in lockstep: `mujoco.rollout` between control instants, the policy once
per instant on the whole batch.

A feedback or learned controller reads the state, so its control sequence is not known before
the episode starts and cannot go to `mujoco.rollout` whole. The plain way is a per-episode
`mj_step` loop that calls the policy once per control step (`reference_episode` here, the
correctness oracle and the speed baseline). The engine instead steps a batch of episodes
together: at each control instant it calls the policy once on every episode's observation, then
`mujoco.rollout` runs the physics steps up to the next instant for the whole batch, on as many
threads as it is given. For a small model the per-call cost of Python and of the policy is then
paid once per batch instead of once per episode.

Results do not depend on the batch: each episode's physics is its own (`mujoco.rollout` sets
each episode's full state before its steps), and the policy must compute each row from that row
alone (`check_batch_independence` tests a policy for it before work, and every batch replays
its recorded observations through the policy in other batches: `check_replayed`). With no
constraint active the solver has no warm start to carry, and the engine's episodes equal the
reference's bit for bit. With one active (a contact, a mocap weld) the solver starts from the
warm start MuJoCo keeps between steps, which `mujoco.rollout` sets to zero at each call: the
reference does the same at each control instant, so the two agree bit for bit there too, and a
plain loop that never resets it differs in the last bits.

Actions: the policy's output columns drive the actuators' ctrl and mocap bodies' targets
(`mjtrial.sim.actuation`); a mocap target goes to `mujoco.rollout` as a control, held until the
next control instant.

Timing: a control instant every `steps_per_control` physics steps; the observation used at
instant k is measured `latency_steps` physics steps earlier (the initial state's while k's time
is within the latency), so sensing latency is a whole number of physics steps.

Sensors: an `Observer` with `sensed=True` is also given the `sensordata` of the measured states,
what `mj_forward` computes at each (`mj_setState` then `mj_forward`: `reference_episode` does
exactly that). `mj_step`, and so `mujoco.rollout`, computes sensors before it integrates: the
sensordata recorded with step j+1 is that of the state after step j. The engine reads them there,
and for a state not yet stepped from (no latency) takes them from one more step that it runs and
discards. Only sensors of the position and velocity stages are read this way (a task's sensor
observation refuses others): they are functions of the state alone, so both ways agree bit for
bit; an acceleration or force sensor would also depend on the control and the solver's warm
start at that instant.
"""

from __future__ import annotations

import copy
from collections.abc import Callable
from dataclasses import dataclass
from typing import Protocol

import mujoco
import numpy as np
from mujoco import rollout

from mjtrial.sim.actuation import MOCAP_SPEC, Actuation, body_poses, initial_targets, qpos_of
from mjtrial.sim.low_level import MakeController, PlainEpisode, Stepper
from mjtrial.sim.physics import FULLPHYSICS

# What mujoco.rollout's control columns hold: the actuators' ctrl, then every body's applied
# wrench (force, torque in the world frame), so pushes travel with the controls.
CONTROL_SPEC = mujoco.mjtState.mjSTATE_CTRL.value | mujoco.mjtState.mjSTATE_XFRC_APPLIED.value


class BatchPolicy(Protocol):
    """A controller over a batch of episodes. Row i of every array is episode i."""

    def reset(self, n_episodes: int) -> None:
        """Start `n_episodes` new episodes (clear any per-episode memory)."""

    def __call__(self, observations: np.ndarray) -> np.ndarray:
        """(n_episodes, n_observations) -> controls (n_episodes, nu)."""


def failed_episodes(policy: BatchPolicy, n: int) -> np.ndarray | None:
    """(n,) the episodes the policy marked failed since its reset, or None if it marks none.

    A policy may judge its own actions: one with a `failed_episodes()` method ((n_episodes,)
    bool, as a policy file marks its non-finite actions: `mjtrial.policy_files.file.OnnxPolicy`) has
    those episodes failed (`ClosedLoopBatch.failed_action`) instead of the run stopped."""
    marked = getattr(policy, "failed_episodes", None)
    return None if marked is None else np.array(marked(), dtype=bool).reshape(n)


class PolicyError(ValueError):
    """The policy returned something the engine cannot apply (shape, non-finite values)."""


@dataclass(frozen=True)
class Timing:
    """When the controller acts, in physics steps."""

    steps_per_control: int  # physics steps between two control instants
    n_controls: int  # control instants per episode
    latency_steps: int = 0  # physics steps between a measurement and the control that uses it

    def __post_init__(self) -> None:
        for name in ("steps_per_control", "n_controls"):
            if getattr(self, name) < 1:
                raise ValueError(f"{name}: expected >= 1, got {getattr(self, name)}")
        if self.latency_steps < 0:
            raise ValueError(f"latency_steps: expected >= 0, got {self.latency_steps}")

    @property
    def n_steps(self) -> int:
        return self.steps_per_control * self.n_controls

    def measured_step(self, k: int) -> int:
        """Index into the physics states of an episode (0: initial, j: after step j) that
        control instant k observes."""
        return max(0, k * self.steps_per_control - self.latency_steps)


@dataclass(frozen=True)
class Pushes:
    """One wrench pulse per episode on one body: `wrench[i]` (force N, torque N m, world
    frame) applied during physics steps `start[i] <= j < stop[i]` (j counts from 0)."""

    body: int
    start: np.ndarray  # (n_episodes,) int
    stop: np.ndarray  # (n_episodes,) int
    wrench: np.ndarray  # (n_episodes, 6)

    def rows(self, index: np.ndarray | slice) -> Pushes:
        return Pushes(self.body, self.start[index], self.stop[index], self.wrench[index])

    def xfrc(self, nbody: int, first_step: int, n_steps: int) -> np.ndarray:
        """(n_episodes, n_steps, nbody * 6) applied wrenches of steps first_step onwards."""
        steps = first_step + np.arange(n_steps)
        on = (steps[None, :] >= self.start[:, None]) & (steps[None, :] < self.stop[:, None])
        out = np.zeros((len(self.start), n_steps, nbody, 6))
        out[:, :, self.body, :] = np.where(on[:, :, None], self.wrench[:, None, :], 0.0)
        return out.reshape(len(self.start), n_steps, nbody * 6)


Observe = Callable[[np.ndarray], np.ndarray]
"""(n_episodes, nstate) mjSTATE_FULLPHYSICS rows -> (n_episodes, n_observations)."""


@dataclass(frozen=True)
class Observer:
    """What the policy is given at each control instant.

    Attributes:
      read: `read(k, states, sensors)`: control instant k, the measured states (n_episodes,
        nstate) mjSTATE_FULLPHYSICS and, when `sensed`, their sensor values (n_episodes,
        nsensordata) (else None) -> (n_episodes, n_observations). Called once per instant, k
        from 0 up, so it may hold what it delivered before (a dropped reading's last value).
      sensed: whether `read` uses the sensor values (their cost is paid only then).
    """

    read: Callable[[int, np.ndarray, np.ndarray | None], np.ndarray]
    sensed: bool = False

    @classmethod
    def of(cls, observe: Observe | Observer) -> Observer:
        """An `Observer` as it is, or one of a function of the measured states alone."""
        if isinstance(observe, Observer):
            return observe
        return cls(lambda k, states, sensors: observe(states))


def sensors_at(models: list[mujoco.MjModel], states: np.ndarray, data: mujoco.MjData) -> np.ndarray:
    """(n, nsensordata) sensor values at each state (n, nstate) mjSTATE_FULLPHYSICS:
    `mj_setState` then `mj_forward` on `data`, episode i on `models[i]`."""
    out = np.empty((len(states), models[0].nsensordata))
    for i, (m, state) in enumerate(zip(models, states, strict=True)):
        mujoco.mj_setState(m, data, state, FULLPHYSICS)
        mujoco.mj_forward(m, data)
        out[i] = data.sensordata
    return out


@dataclass(frozen=True)
class ClosedLoopBatch:
    """Trajectories of a batch of closed-loop episodes.

    Attributes:
      physics: (n_episodes, n_steps, nstate) mjSTATE_FULLPHYSICS after each physics step.
      sensordata: (n_episodes, n_steps, nsensordata) the sensors each physics step recorded,
        computed before it integrates: [:, j] are those of the state before step j + 1.
      ctrl: (n_episodes, n_controls, nu) the controls the policy chose at each instant.
      warnings: (mjNWARNING,) warning counters of a `reference_episode` (None from the engine,
        which, like `mujoco.rollout`, reports only the frozen state).
      failed_action: (n_episodes,) True where the policy marked its own action failed
        (`failed_episodes`), or None for a policy that marks none.
      mocap: (n_episodes, n_controls, nmocap, 7) the mocap targets (pos, quat w-x-y-z) set at
        each instant, or None when the policy moves no mocap body.
      applied: (n_episodes, n_steps, nu) the controls at each physics step when a low-level
        controller computed them (`mjtrial.sim.low_level`; `ctrl` then holds the policy's actions,
        (n_episodes, n_controls, n_inputs)), else None: `ctrl` held over each control period.
    """

    physics: np.ndarray
    sensordata: np.ndarray
    ctrl: np.ndarray
    warnings: np.ndarray | None = None
    failed_action: np.ndarray | None = None
    mocap: np.ndarray | None = None
    applied: np.ndarray | None = None

    def applied_controls(self, steps_per_control: int) -> np.ndarray:
        """(n_episodes, n_steps, nu) the controls that acted at each physics step."""
        if self.applied is not None:
            return self.applied
        return np.repeat(self.ctrl, steps_per_control, axis=1)


def _checked_controls(ctrl: object, n: int, nu: int) -> np.ndarray:
    """The policy's answer (n, nu), nu its output columns (every actuator's ctrl unless the
    task declares actions: `mjtrial.sim.actuation`)."""
    ctrl = np.asarray(ctrl, dtype=np.float64)
    if ctrl.shape != (n, nu):
        raise PolicyError(f"policy: expected controls of shape ({n}, {nu}), got {ctrl.shape}")
    if not np.isfinite(ctrl).all():
        rows = np.flatnonzero(~np.isfinite(ctrl).all(axis=1))
        raise PolicyError(
            f"policy: non-finite controls for {len(rows)} episode(s), e.g. row {rows[0]}"
        )
    return ctrl


def _pose_state(initial: np.ndarray, physics: np.ndarray, step: int) -> np.ndarray:
    """(n, nstate) the states whose kinematics `data.xpos` holds after `step` physics steps:
    `mj_step` computes positions before it integrates, so a plain loop that reads the welded
    body's pose after stepping (gymnasium-robotics' `reset_mocap2body_xpos`) reads the pose of
    the state one step before; at the start, the reset's `mj_forward` gives the initial one."""
    return initial if step < 2 else physics[:, step - 2]


def run_batch(
    models: list[mujoco.MjModel],
    initial: np.ndarray,
    policy: BatchPolicy,
    observe: Observe | Observer,
    timing: Timing,
    *,
    runner: rollout.Rollout,
    datas: list[mujoco.MjData],
    pushes: Pushes | None = None,
    check: bool = True,
    actuation: Actuation | None = None,
    low_level: MakeController | None = None,
    carry_warmstart: bool = False,
) -> ClosedLoopBatch:
    """Run a batch of closed-loop episodes in lockstep.

    Args:
      models: one model per episode (the same sizes; per-episode physical parameters).
      initial: (n_episodes, nstate) mjSTATE_FULLPHYSICS initial states.
      policy: called once per control instant on all the batch's observations.
      observe: the observations of a batch of physics states (an `Observer`, or a function of
        the measured states alone).
      timing: control period, episode length and sensing latency in physics steps.
      runner: a `mujoco.rollout.Rollout` (its thread pool is reused across batches).
      datas: one MjData per runner thread (at least one).
      pushes: a wrench pulse per episode, or None.
      check: replay every instant's observations through the policy, each row alone
        (`check_replayed`), and raise `PolicyError` if a row's controls differ; off only where
        the episodes are a search's scores (`engine.iter_batches`'s `replay_check`) or to
        measure its cost.
      actuation: what the policy's output columns drive (default: every actuator's ctrl); one
        that moves mocap bodies has their targets sent to `mujoco.rollout` as controls, from
        each episode's start pose (its model's, `actuation.initial_targets`).
      low_level: builds the low-level controller the policy's actions go to, run at every
        physics step (`mjtrial.sim.low_level`) on as many threads as `datas` has entries; None: the
        actions drive the actuators (`actuation`) and `mujoco.rollout` steps the physics.
      carry_warmstart: carry each episode's solver warm start from one control period to the
        next, as a suite's own `mj_step` loop does (`mujoco.rollout` starts each call from a
        given warm start, zero by default): each episode's block then is a `rollout` call of
        its own, on the calling thread, from the warm start its last block left in `datas[0]`
        (about 2 % slower on the Fetch than one call for the batch). A low-level controller
        always carries it (each episode keeps its `MjData`).
    """
    if low_level is not None:
        return _run_low_level(
            models, initial, policy, observe, timing, low_level,
            nthread=len(datas), pushes=pushes, check=check,
        )
    n, nstate = initial.shape
    model = models[0]
    nu, nbody, s = model.nu, model.nbody, timing.steps_per_control
    actuation = actuation or Actuation.every_actuator(model)
    moves = actuation.moves_mocap
    targets = initial_targets(models) if moves else None
    mocap_log = np.empty((n, timing.n_controls, model.nmocap, 7)) if moves else None
    scratch = mujoco.MjData(model) if actuation.welded_bodies else None
    spec = CONTROL_SPEC | MOCAP_SPEC if moves else CONTROL_SPEC
    observer = Observer.of(observe)
    physics = np.empty((n, timing.n_steps, nstate))
    sensordata = np.empty((n, timing.n_steps, model.nsensordata))
    ctrl_log = np.empty((n, timing.n_controls, nu))
    # With no latency a sensed observation reads the state each block ends in, not yet stepped
    # from: one more step gives its sensors (the module's docstring), then is discarded.
    extra = int(observer.sensed and timing.latency_steps == 0 and not carry_warmstart)
    warmstart = np.zeros((n, model.nv)) if carry_warmstart else None
    probe = mujoco.MjData(model) if observer.sensed and carry_warmstart else None
    # the calling thread's rollout, whose one data keeps the warm start each episode left
    serial = rollout.Rollout(nthread=0) if carry_warmstart else None
    # Preallocated rollout outputs and controls, reused every call (skip_checks needs them whole).
    step_states = np.empty((n, s + extra, nstate))
    step_sensors = np.empty((n, s + extra, model.nsensordata))
    controls = np.zeros((n, s + extra, nu + nbody * 6 + (model.nmocap * 7 if moves else 0)))
    state = np.ascontiguousarray(initial, dtype=np.float64)
    initial_sensors = sensors_at(models, state, mujoco.MjData(model)) if observer.sensed else None
    replayed = timing.n_controls if check else 0  # every instant: `check_replayed`
    observed: np.ndarray | None = None  # (n, replayed, n_observations), for check_replayed
    answered = np.empty((n, replayed, actuation.n_outputs))  # what the policy gave them
    policy.reset(n)
    for k in range(timing.n_controls):
        j = timing.measured_step(k)
        measured = initial if j == 0 else physics[:, j - 1]
        sensors = None
        if observer.sensed:  # the sensors of state j were computed in step j + 1
            sensors = (
                initial_sensors
                if j == 0
                else sensordata[:, j]
                if j < k * s
                else step_sensors[:, s]
                if probe is None
                else sensors_at(models, measured, probe)
            )
        obs = np.asarray(observer.read(k, measured, sensors), dtype=np.float64)
        if k < replayed:
            if observed is None:
                observed = np.empty((n, replayed, *obs.shape[1:]))
            observed[:, k] = obs  # a copy: the policy may change its argument
        answer = _checked_controls(policy(obs), n, actuation.n_outputs)
        if k < replayed:
            answered[:, k] = answer
        welded = (
            body_poses(
                models, _pose_state(initial, physics, k * s), actuation.welded_bodies, scratch
            )
            if scratch
            else None
        )
        ctrl, targets = actuation.apply(answer, qpos_of(state, model.nq), targets, welded)
        ctrl_log[:, k] = ctrl
        controls[:, :, :nu] = ctrl[:, None, :]
        if pushes is not None:
            controls[:, :, nu : nu + nbody * 6] = pushes.xfrc(nbody, k * s, s + extra)
        if moves:
            mocap_log[:, k] = targets
            pos, quat = targets[:, :, :3], targets[:, :, 3:]
            at = nu + nbody * 6
            controls[:, :, at : at + pos[0].size] = pos.reshape(n, 1, -1)
            controls[:, :, at + pos[0].size :] = quat.reshape(n, 1, -1)
        if warmstart is None:
            runner.rollout(
                models,
                datas,
                state,
                controls,
                control_spec=spec,
                skip_checks=True,
                nstep=s + extra,
                state=step_states,
                sensordata=step_sensors,
                chunk_size=-(-n // len(datas)),
            )
        else:  # each episode alone, from the warm start its last block left in datas[0]
            for i in range(n):
                serial.rollout(
                    models[i : i + 1],
                    datas[:1],
                    state[i : i + 1],
                    controls[i : i + 1],
                    control_spec=spec,
                    skip_checks=True,
                    nstep=s,
                    initial_warmstart=warmstart[i : i + 1],
                    state=step_states[i : i + 1],
                    sensordata=step_sensors[i : i + 1],
                    chunk_size=1,
                )
                warmstart[i] = datas[0].qacc_warmstart
        physics[:, k * s : (k + 1) * s] = step_states[:, :s]
        sensordata[:, k * s : (k + 1) * s] = step_sensors[:, :s]
        state = np.ascontiguousarray(step_states[:, s - 1])
    if serial is not None:
        serial.close()
    failed = failed_episodes(policy, n)  # before the replay resets the policy
    if observed is not None:
        check_replayed(policy, observed, answered)
    return ClosedLoopBatch(
        physics=physics,
        sensordata=sensordata,
        ctrl=ctrl_log,
        failed_action=failed,
        mocap=mocap_log,
    )


def _run_low_level(
    models: list[mujoco.MjModel],
    initial: np.ndarray,
    policy: BatchPolicy,
    observe: Observe | Observer,
    timing: Timing,
    low_level: MakeController,
    *,
    nthread: int,
    pushes: Pushes | None,
    check: bool,
) -> ClosedLoopBatch:
    """`run_batch` with a low-level controller between the policy and the actuators: the policy
    once per control instant on the whole batch, the physics a step at a time
    (`low_level.Stepper`), each episode on its own `MjData` throughout."""
    n, nstate = initial.shape
    model = models[0]
    s = timing.steps_per_control
    observer = Observer.of(observe)
    stepper = Stepper(models, initial, low_level, nthread=nthread, pushes=pushes)
    n_inputs = stepper.slices[0].controller.n_inputs
    physics = np.empty((n, timing.n_steps, nstate))
    sensordata = np.empty((n, timing.n_steps, model.nsensordata))
    applied = np.empty((n, timing.n_steps, model.nu))
    actions = np.empty((n, timing.n_controls, n_inputs))
    probe = mujoco.MjData(model) if observer.sensed else None
    replayed = timing.n_controls if check else 0
    observed: np.ndarray | None = None
    policy.reset(n)
    try:
        for k in range(timing.n_controls):
            j = timing.measured_step(k)
            measured = initial if j == 0 else physics[:, j - 1]
            sensors = None
            if probe is not None:  # state j's sensors were computed in step j + 1, if it ran
                sensors = sensordata[:, j] if j < k * s else sensors_at(models, measured, probe)
            obs = np.asarray(observer.read(k, measured, sensors), dtype=np.float64)
            if k < replayed:
                if observed is None:
                    observed = np.empty((n, replayed, *obs.shape[1:]))
                observed[:, k] = obs
            actions[:, k] = _checked_controls(policy(obs), n, n_inputs)
            stepper.block(actions[:, k], k * s, s, physics, sensordata, applied)
    finally:
        stepper.close()
    failed = failed_episodes(policy, n)
    if observed is not None:
        check_replayed(policy, observed, actions[:, :replayed])
    return ClosedLoopBatch(
        physics=physics,
        sensordata=sensordata,
        ctrl=actions,
        failed_action=failed,
        applied=applied,
    )


def reference_episode(
    model: mujoco.MjModel,
    initial: np.ndarray,
    policy: BatchPolicy,
    observe: Observe | Observer,
    timing: Timing,
    *,
    pushes: Pushes | None = None,
    actuation: Actuation | None = None,
    low_level: MakeController | None = None,
    carry_warmstart: bool = False,
) -> ClosedLoopBatch:
    """One episode with plain `mj_step`, the policy called once per control step on a batch of
    one: what a user writes without the engine, and the engine's reference.

    With a `low_level` controller the loop is `mj_step1`, the controller, `mj_step2` at every
    physics step, the policy's latest action given to the controller (`low_level.PlainEpisode`),
    on one `MjData` throughout: the warm start is carried from step to step.

    Like `mujoco.rollout`, it stops stepping at the first MuJoCo warning and repeats the frozen
    state. A sensed observation's sensors are computed at the measured state by `mj_setState`
    and `mj_forward` on an MjData of their own. The actions (`actuation`) are written where a
    user writes them: `data.ctrl`, and `data.mocap_pos` / `data.mocap_quat` from the mocap's
    previous target there or the welded body's `data.xpos` / `data.xquat` as the last `mj_step`
    left them (`_pose_state`). Returns a batch of one episode.
    """
    observer = Observer.of(observe)
    if low_level is not None:
        return _reference_low_level(model, initial, policy, observer, timing, low_level, pushes)
    m = copy.copy(model)
    d = mujoco.MjData(m)
    probe = mujoco.MjData(m) if observer.sensed else None
    mujoco.mj_setState(m, d, initial, FULLPHYSICS)
    actuation = actuation or Actuation.every_actuator(m)
    welded = list(actuation.welded_bodies)
    nstate = initial.shape[0]
    states = [np.asarray(initial, dtype=np.float64)]
    sensors = []
    ctrl_log = np.empty((timing.n_controls, m.nu))
    mocap_log = np.empty((timing.n_controls, m.nmocap, 7))
    policy.reset(1)
    halted = False
    for k in range(timing.n_controls):
        measured = states[timing.measured_step(k)][None]
        sensed = sensors_at([m], measured, probe) if probe is not None else None
        obs = np.asarray(observer.read(k, measured, sensed))
        answer = _checked_controls(policy(obs), 1, actuation.n_outputs)
        if welded and k == 0:  # later, `data.xpos` is what the last `mj_step` left
            mujoco.mj_kinematics(m, d)
        target = np.concatenate([d.mocap_pos, d.mocap_quat], axis=1)[None]
        pose = np.concatenate([d.xpos[welded], d.xquat[welded]], axis=1)[None]
        ctrl, target = actuation.apply(answer, d.qpos[None].copy(), target, pose)
        ctrl_log[k] = ctrl[0]
        mocap_log[k] = target[0]
        # `mujoco.rollout` starts each control block from a zero warm start, and so does this
        # unless the warm start is carried: with a constraint active (a weld, a contact) the
        # solver's result depends on it
        if not carry_warmstart:
            d.qacc_warmstart[:] = 0.0
        d.ctrl[:] = ctrl[0]
        if actuation.moves_mocap:
            d.mocap_pos[:] = target[0, :, :3]
            d.mocap_quat[:] = target[0, :, 3:]
        for j in range(k * timing.steps_per_control, (k + 1) * timing.steps_per_control):
            if pushes is not None:
                d.xfrc_applied[:] = 0.0
                if pushes.start[0] <= j < pushes.stop[0]:
                    d.xfrc_applied[pushes.body] = pushes.wrench[0]
            if not halted and any(w.number for w in d.warning):
                halted = True
            if not halted:
                mujoco.mj_step(m, d)
            row = np.empty(nstate)
            mujoco.mj_getState(m, d, row, FULLPHYSICS)
            states.append(row)
            sensors.append(d.sensordata.copy())
    return ClosedLoopBatch(
        physics=np.stack(states[1:])[None],
        sensordata=np.stack(sensors).reshape(1, len(sensors), m.nsensordata),
        ctrl=ctrl_log[None],
        warnings=np.array([w.number for w in d.warning]),
        failed_action=failed_episodes(policy, 1),
        mocap=mocap_log[None] if actuation.moves_mocap else None,
    )


def _reference_low_level(
    model: mujoco.MjModel,
    initial: np.ndarray,
    policy: BatchPolicy,
    observer: Observer,
    timing: Timing,
    low_level: MakeController,
    pushes: Pushes | None,
) -> ClosedLoopBatch:
    """`reference_episode` with a low-level controller (see there)."""
    episode = PlainEpisode(model, initial, low_level())
    probe = mujoco.MjData(episode.m) if observer.sensed else None
    states = [np.asarray(initial, dtype=np.float64)]
    sensors, applied = [], []
    actions = np.empty((timing.n_controls, episode.controller.n_inputs))
    policy.reset(1)
    s = timing.steps_per_control
    for k in range(timing.n_controls):
        measured = states[timing.measured_step(k)][None]
        sensed = sensors_at([episode.m], measured, probe) if probe is not None else None
        obs = np.asarray(observer.read(k, measured, sensed))
        actions[k] = _checked_controls(policy(obs), 1, actions.shape[1])[0]
        for j in range(k * s, (k + 1) * s):
            push = None
            if pushes is not None:
                on = pushes.start[0] <= j < pushes.stop[0]
                push = pushes.wrench[0] if on else np.zeros(6)
            row, sensordata, ctrl = episode.step(
                actions[k], j == k * s, push, pushes.body if pushes else 0
            )
            states.append(row)
            sensors.append(sensordata)
            applied.append(ctrl)
    return ClosedLoopBatch(
        physics=np.stack(states[1:])[None],
        sensordata=np.stack(sensors).reshape(1, len(sensors), episode.m.nsensordata),
        ctrl=actions[None],
        warnings=np.array([w.number for w in episode.d.warning]),
        failed_action=failed_episodes(policy, 1),
        applied=np.stack(applied)[None],
    )


def check_batch_independence(policy: BatchPolicy, observations: np.ndarray) -> None:
    """Raise `PolicyError` unless the policy gives every row the same controls alone as in the
    batch, bit for bit: an episode's result must not depend on which batch it ran in."""
    n = len(observations)
    policy.reset(n)
    together = np.asarray(policy(observations), dtype=np.float64)
    # the shape first: a transposed (nu, n) answer is a wrong shape, not a batch dependence
    if together.ndim != 2 or together.shape[0] != n:
        raise PolicyError(
            f"policy: expected controls of shape ({n}, nu), one row per episode of a batch of "
            f"{n}, got {together.shape}"
        )
    for i in range(n):
        policy.reset(1)
        alone = _checked_controls(policy(observations[i : i + 1]), 1, together.shape[1])
        if not np.array_equal(alone[0], together[i], equal_nan=True):
            diff = float(np.max(np.abs(alone[0] - together[i])))
            raise PolicyError(
                f"policy: row {i} alone gives other controls than in a batch of {n} "
                f"(largest difference {diff:.3g}); compute each row from that row alone "
                "(elementwise arithmetic, not a matrix product whose summation order depends on "
                "the batch)"
            )


def replay_splits(n: int) -> list[np.ndarray]:
    """The batches a batch's rows 0..n-1 are replayed in: each row alone, the batch of one that
    the reference runs and verify re-simulates. A row's controls alone are what they must be in
    any batch; a replay in other batches of several rows (halves of it), or of the first 20
    instants, let through a policy that changes only after instant 25 in batches of more than 8
    rows. The cost, on the built-in closed-loop experiment (250 instants, 200 episodes a shard,
    its LQR policy): about 0.8 s of CPU per shard, where its episodes take about 0.9 s. None for
    a batch of one row."""
    if n < 2:
        return []
    return [np.array([i]) for i in range(n)]


def check_replayed(policy: BatchPolicy, observations: np.ndarray, controls: np.ndarray) -> None:
    """Raise `PolicyError` unless the policy, given the same observations from its reset on but
    each row alone (`replay_splits`), gives every row the controls it gave in the batch, bit for
    bit, at every instant: an episode's controls, and so its result, must not depend on its
    batch (the shard's size, the episodes beside it).

    A policy with an `alone(observations)` method (k instants of one episode -> its (k, nu)
    controls, what a reset and k calls on that row alone give) replays each episode through it:
    a policy file does (`policy_file.OnnxPolicy.alone`, its graph called on the row alone at
    every instant and the arithmetic around it once per episode), and so do the built-in
    controllers (`mjtrial.sim.controllers`, the whole episode in one pass).

    Args:
      policy: the batch's policy (reset here; its memory is per episode from a reset on).
      observations: (n, k, n_observations) what the policy saw at its first k instants.
      controls: (n, k, nu) what it returned.
    """
    n, n_controls, nu = controls.shape
    alone = getattr(policy, "alone", None)  # a policy's own replay of one episode (see above)
    for rows in replay_splits(n):
        if alone is not None and len(rows) == 1:
            ctrl = np.asarray(alone(observations[rows[0]].copy()), dtype=np.float64)
            if ctrl.shape != (n_controls, nu):
                raise PolicyError(
                    f"policy: expected controls of shape ({n_controls}, {nu}) from alone(), got "
                    f"{ctrl.shape}"
                )
            again = ctrl[:, None, :]
        else:
            policy.reset(len(rows))
            again = np.empty((n_controls, len(rows), nu))
            for k in range(n_controls):  # compared once the episode is replayed: cheaper
                ctrl = np.asarray(policy(observations[rows, k].copy()), dtype=np.float64)
                if ctrl.shape != (len(rows), nu):
                    raise PolicyError(
                        f"policy: expected controls of shape ({len(rows)}, {nu}), got "
                        f"{ctrl.shape}"
                    )
                again[k] = ctrl
        given = controls[rows].swapaxes(0, 1)  # (k, rows, nu), finite (`_checked_controls`)
        if np.array_equal(again, given):
            continue
        k, bad = (int(x[0]) for x in np.nonzero((again != given).any(axis=2)))
        diff = float(np.max(np.abs(again[k, bad] - given[k, bad])))
        how = "it runs alone" if len(rows) == 1 else f"replayed in a batch of {len(rows)}"
        raise PolicyError(
            f"policy: batch dependence: episode row {rows[bad]} of a batch of {n} gets other "
            f"controls at control instant {k} when {how} (largest difference {diff:.3g}): "
            "its results would depend on the batch (rollout.shard_size); compute each row "
            "from that row's observations alone"
        )
