"""Episodes of the protocol: a literal reference stepper and the engine the pipeline runs.

The engine precomputes the open-loop control sequence and runs it with `mujoco.rollout` over
per-episode model copies (each episode has its own cube mass). The reference follows the
protocol step by step with plain `mj_step`; a test asserts both give identical results.

Both end an episode at its first MuJoCo warning, freezing the state from then on: that is what
`mujoco.rollout` does, and such an episode is an unhealthy failure, not a crash.
"""

from __future__ import annotations

import copy
from collections.abc import Iterator
from dataclasses import dataclass

import mujoco
import numpy as np
from mujoco import rollout

from mjtrial.sim.engine import warning_names
from mjtrial.sim.physics import FULLPHYSICS, halted, nonfinite, steps_simulated

from .model_spec import ModelSpec
from .protocol import CTRL_GRIPPER, CTRL_Z, PROTOCOL, Protocol, control_sequence, hold_steps
from .states import InitialState


def yaw_quaternion(yaw: float) -> np.ndarray:
    """Rotation about z as a MuJoCo w-x-y-z quaternion."""
    return np.array([np.cos(yaw / 2), 0.0, 0.0, np.sin(yaw / 2)])


def episode_model(
    model: mujoco.MjModel, mass: float, *, scratch: mujoco.MjData | None = None
) -> mujoco.MjModel:
    """A copy of `model` whose cube has `mass` kg (inertia as compiled), constants recomputed.

    `scratch`, any MjData of a model of the same sizes, saves an allocation per episode:
    `mj_setConst` only uses it as workspace.
    """
    episode = copy.copy(model)
    episode.body_mass[ModelSpec.of(model).cube_body] = mass
    mujoco.mj_setConst(episode, scratch if scratch is not None else mujoco.MjData(episode))
    return episode


def initial_physics_state(
    model: mujoco.MjModel,
    state: InitialState,
    *,
    protocol: Protocol = PROTOCOL,
    scratch: mujoco.MjData | None = None,
) -> np.ndarray:
    """The mjSTATE_FULLPHYSICS vector an episode starts from, for its own `episode_model`.

    `scratch` (any MjData of a same-sized model) is reset here, so it may be reused.
    """
    data = scratch if scratch is not None else mujoco.MjData(model)
    mujoco.mj_resetDataKeyframe(model, data, 0)
    adr = ModelSpec.of(model).cube_qpos
    data.qpos[adr : adr + 3] = (protocol.home_x + state.dx, state.dy, protocol.cube_z)
    data.qpos[adr + 3 : adr + 7] = yaw_quaternion(state.yaw)
    out = np.empty(mujoco.mj_stateSize(model, FULLPHYSICS))
    mujoco.mj_getState(model, data, out, FULLPHYSICS)
    return out


# Episodes per `mujoco.rollout` call. Each episode of a batch holds its own model copy and
# trajectories until the batch is classified and handed to the recording writer: 16 keep a
# rollout job's working memory near 20-30 MB (64 took about 85 MB), and the per-call cost is
# still small beside 16 episodes' stepping.
BATCH_SIZE = 16


@dataclass(frozen=True)
class EpisodeBatch:
    """Trajectories of a batch of episodes, as `mujoco.rollout` returns them.

    Attributes:
      states: the batch's initial states, length n_episodes.
      physics: (n_episodes, n_steps, nstate) mjSTATE_FULLPHYSICS after each step.
      sensordata: (n_episodes, n_steps, nsensordata) sensor values after each step.
    """

    states: list[InitialState]
    physics: np.ndarray
    sensordata: np.ndarray


def iter_episode_batches(
    model: mujoco.MjModel,
    states: list[InitialState],
    *,
    lift_time: float,
    nthread: int,
    batch_size: int = BATCH_SIZE,
    protocol: Protocol = PROTOCOL,
) -> Iterator[EpisodeBatch]:
    """Run episodes with `mujoco.rollout`, `batch_size` at a time so memory stays bounded.

    Results do not depend on `batch_size` or `nthread`: each episode starts from its own full
    state with a zero warm start.
    """
    if batch_size < 1:
        raise ValueError(f"batch_size: expected >= 1, got {batch_size}")
    ctrl, _ = control_sequence(lift_time, timestep=model.opt.timestep, protocol=protocol)
    datas = [mujoco.MjData(model) for _ in range(max(1, nthread))]
    scratch = mujoco.MjData(model)
    with rollout.Rollout(nthread=nthread if nthread > 1 else 0) as runner:
        for start in range(0, len(states), batch_size):
            batch = states[start : start + batch_size]
            models = [episode_model(model, s.mass, scratch=scratch) for s in batch]
            initial = np.stack(
                [
                    initial_physics_state(m, s, protocol=protocol, scratch=scratch)
                    for m, s in zip(models, batch, strict=True)
                ]
            )
            physics, sensordata = runner.rollout(models, datas, initial, ctrl[None])
            yield EpisodeBatch(states=batch, physics=physics, sensordata=sensordata)


def reference_episode(
    model: mujoco.MjModel, state: InitialState, *, lift_time: float, protocol: Protocol = PROTOCOL
) -> tuple[np.ndarray, np.ndarray]:
    """Follow the protocol literally with plain `mj_step`: the reference for the engine.

    Returns:
      physics: (n_steps, nstate) mjSTATE_FULLPHYSICS after each step.
      warnings: (mjNWARNING,) warning counters of the run (non-zero: ended early).
    """
    p = protocol
    m = copy.copy(model)
    d = mujoco.MjData(m)
    # 1. reset, set the cube's mass, recompute constants, place the cube.
    mujoco.mj_resetDataKeyframe(m, d, 0)
    spec = ModelSpec.of(m)
    m.body_mass[spec.cube_body] = state.mass
    mujoco.mj_setConst(m, d)
    mujoco.mj_resetDataKeyframe(m, d, 0)
    adr = spec.cube_qpos
    d.qpos[adr : adr + 3] = (p.home_x + state.dx, state.dy, p.cube_z)
    d.qpos[adr + 3 : adr + 7] = (np.cos(state.yaw / 2), 0, 0, np.sin(state.yaw / 2))
    d.ctrl[:] = (p.home_x, 0.0, p.z_up, p.gripper_open)

    nstate = mujoco.mj_stateSize(m, FULLPHYSICS)
    out: list[np.ndarray] = []
    halted = False

    def hold(duration: float) -> None:
        nonlocal halted
        for _ in range(hold_steps(duration, m.opt.timestep)):
            if not halted and any(w.number for w in d.warning):
                halted = True
            if not halted:
                mujoco.mj_step(m, d)
            row = np.empty(nstate)
            mujoco.mj_getState(m, d, row, FULLPHYSICS)
            out.append(row)

    # 2. settle, then descend in 100 set-points.
    hold(p.settle_time)
    for k in range(p.descend_segments):
        d.ctrl[CTRL_Z] = p.z_down * (k + 1) / p.descend_segments
        hold(p.segment_time)
    # 3. wait, then close the gripper.
    hold(p.pre_close_time)
    d.ctrl[CTRL_GRIPPER] = p.gripper_closed
    hold(p.close_time)
    # 4. lift over lift_time, one set-point per 10 ms.
    steps = max(1, round(lift_time / p.segment_time))
    for k in range(steps):
        d.ctrl[CTRL_Z] = p.z_down + (p.z_up - p.z_down) * (k + 1) / steps
        hold(lift_time / steps)
    # 5. hold; success is judged on the last state.
    hold(p.hold_time)
    warnings = np.array([w.number for w in d.warning])
    return np.stack(out), warnings


# Columns of the per-episode table, in order (one place for each column's name).
EPISODE_COLUMNS = (
    "state_id",
    "success",
    "final_height",
    "final_x",
    "final_y",
    "steps_simulated",
    "nonfinite",
    "warning",
)


def episode_outcomes(
    model: mujoco.MjModel,
    batch: EpisodeBatch,
    *,
    lift_time: float,
    protocol: Protocol = PROTOCOL,
) -> dict[str, np.ndarray]:
    """Per-episode results of a batch, keyed by `EPISODE_COLUMNS`.

    An episode that stopped early (a MuJoCo warning froze its state) or went non-finite is a
    failure; its warning is named by re-running it with the reference stepper, which is rare
    and so costs nothing in a healthy experiment.
    """
    # A copy: the columns below must not keep the whole batch's trajectories alive (a view
    # would, and a job that keeps every batch's columns would hold every trajectory).
    final = batch.physics[:, -1, :].copy()
    spec = ModelSpec.of(model)
    stopped, broken = halted(batch.physics), nonfinite(batch.physics)
    height = final[:, spec.state_cube_z]
    success = (height > protocol.success_height) & ~stopped & ~broken
    warning = np.full(len(batch.states), "", dtype=object)
    for i in np.flatnonzero(stopped | broken):
        _, counters = reference_episode(
            model, batch.states[i], lift_time=lift_time, protocol=protocol
        )
        warning[i] = warning_names(counters)
    return {
        "state_id": np.array([s.state_id for s in batch.states], dtype=np.int64),
        "success": success,
        "final_height": height,
        "final_x": final[:, spec.state_cube_position.start],
        "final_y": final[:, spec.state_cube_position.start + 1],
        "steps_simulated": steps_simulated(batch.physics),
        "nonfinite": broken,
        "warning": warning,
    }
