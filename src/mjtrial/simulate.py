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
from pathlib import Path

import mujoco
import numpy as np
from mujoco import rollout

from mjtrial.protocol import CTRL_GRIPPER, CTRL_Z, PROTOCOL, Protocol, control_sequence, hold_steps

CUBE_BODY = "cube"
N_ACTUATORS = 4
FULLPHYSICS = mujoco.mjtState.mjSTATE_FULLPHYSICS.value
# Layout of an mjSTATE_FULLPHYSICS vector: time, qpos, qvel, act, ...
STATE_TIME = 0
STATE_QPOS = 1


@dataclass(frozen=True)
class InitialState:
    """One randomized initial state: cube offset (m), yaw (rad) and mass (kg)."""

    state_id: int
    dx: float
    dy: float
    yaw: float
    mass: float


class ModelError(ValueError):
    """The model file is missing, malformed, or lacks what the protocol needs."""


def load_model(path: str | Path) -> mujoco.MjModel:
    """Load and check a model for the protocol: a body named `cube` on a free joint, 4 actuators."""
    path = Path(path)
    if not path.is_file():
        raise ModelError(f"{path}: model file not found")
    try:
        model = mujoco.MjModel.from_xml_path(str(path))
    except ValueError as err:
        first = str(err).strip().splitlines()[0] if str(err).strip() else "compile error"
        raise ModelError(f"{path}: MuJoCo could not compile the model: {first}") from None
    cube = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_BODY, CUBE_BODY)
    if cube < 0:
        raise ModelError(f"{path}: expected a body named {CUBE_BODY!r}, found none")
    jnt = model.body_jntadr[cube]
    if model.body_jntnum[cube] != 1 or model.jnt_type[jnt] != mujoco.mjtJoint.mjJNT_FREE:
        raise ModelError(f"{path}: body {CUBE_BODY!r}: expected exactly one free joint")
    if model.nu != N_ACTUATORS:
        raise ModelError(
            f"{path}: expected {N_ACTUATORS} actuators (x, y, z, gripper), found {model.nu}"
        )
    if model.nkey < 1:
        raise ModelError(f"{path}: expected a home keyframe (keyframe 0), found none")
    return model


def cube_qpos_address(model: mujoco.MjModel) -> int:
    """Index in qpos of the cube's free joint (position, then w-x-y-z quaternion)."""
    cube = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_BODY, CUBE_BODY)
    return int(model.jnt_qposadr[model.body_jntadr[cube]])


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
    cube = mujoco.mj_name2id(episode, mujoco.mjtObj.mjOBJ_BODY, CUBE_BODY)
    episode.body_mass[cube] = mass
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
    adr = cube_qpos_address(model)
    data.qpos[adr : adr + 3] = (protocol.home_x + state.dx, state.dy, protocol.cube_z)
    data.qpos[adr + 3 : adr + 7] = yaw_quaternion(state.yaw)
    out = np.empty(mujoco.mj_stateSize(model, FULLPHYSICS))
    mujoco.mj_getState(model, data, out, FULLPHYSICS)
    return out


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
    batch_size: int = 64,
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
    cube = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_BODY, CUBE_BODY)
    m.body_mass[cube] = state.mass
    mujoco.mj_setConst(m, d)
    mujoco.mj_resetDataKeyframe(m, d, 0)
    adr = m.jnt_qposadr[m.body_jntadr[cube]]
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


def cube_height(model: mujoco.MjModel, physics: np.ndarray) -> np.ndarray:
    """Cube centre height from mjSTATE_FULLPHYSICS vectors, shape (..., nstate) -> (...)."""
    return physics[..., STATE_QPOS + cube_qpos_address(model) + 2]


def warning_names(counters: np.ndarray) -> str:
    """MuJoCo warnings that fired, by name (e.g. "mjWARN_BADQACC"), comma-separated."""
    return ",".join(mujoco.mjtWarning(i).name for i, n in enumerate(counters) if n)


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
    final = batch.physics[:, -1, :]
    adr = STATE_QPOS + cube_qpos_address(model)
    # A warning freezes the state (mujoco.rollout stops stepping), and a bad acceleration
    # resets it first, so time is not a step counter: the first repeated time is the halt.
    frozen = np.diff(batch.physics[:, :, STATE_TIME], axis=1) == 0
    halted = frozen.any(axis=1)
    steps = np.where(halted, frozen.argmax(axis=1) + 1, batch.physics.shape[1]).astype(np.int64)
    nonfinite = ~np.isfinite(batch.physics).all(axis=(1, 2))
    height = final[:, adr + 2]
    success = (height > protocol.success_height) & ~halted & ~nonfinite
    warning = np.full(len(batch.states), "", dtype=object)
    for i in np.flatnonzero(halted | nonfinite):
        _, counters = reference_episode(
            model, batch.states[i], lift_time=lift_time, protocol=protocol
        )
        warning[i] = warning_names(counters)
    return {
        "state_id": np.array([s.state_id for s in batch.states], dtype=np.int64),
        "success": success,
        "final_height": height,
        "final_x": final[:, adr],
        "final_y": final[:, adr + 1],
        "steps_simulated": steps,
        "nonfinite": nonfinite,
        "warning": warning,
    }
