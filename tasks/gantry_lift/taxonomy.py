"""Why a lift failed: one category per failed episode, from its trajectory and contacts.

Computed in the rollout stage from the states and sensor values `mujoco.rollout` already
returned, so it costs no second simulation. The categories are checked in a fixed order and
the first that applies wins, so every failed episode gets exactly one:

1. simulation unhealthy: a MuJoCo warning stopped the episode, or its state went non-finite;
2. knocked or flung away: the cube left the workspace (its centre moved more than
   `workspace_radius` from the gripper axis) or tilted past `max_tilt`, before the grasp was
   lost (a cube that slips and then tumbles on landing is a slip, not a knock);
3. never grasped: the cube's centre never rose `lifted_height` above where it started;
4. slipped during the lift: the grasp was first lost during the lift, lost meaning the cube
   slid down the pads by more than `slip_distance` since the lift began, or no pad touched it;
5. dropped during the hold: the grasp was first lost during the hold after the lift.
"""

from __future__ import annotations

import enum
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import mujoco
import numpy as np

from mjtrial.sim.physics import healthy

from .model_spec import ModelSpec
from .protocol import Phase


class FailureCategory(enum.Enum):
    """Failure categories, in the order they are checked."""

    UNHEALTHY = "simulation unhealthy"
    KNOCKED = "knocked or flung away"
    NEVER_GRASPED = "never grasped"
    SLIPPED = "slipped during the lift"
    DROPPED = "dropped during the hold"


@dataclass(frozen=True)
class Thresholds:
    """The taxonomy's thresholds (config `failure_taxonomy`), in m and rad."""

    lifted_height: float = 0.03
    slip_distance: float = 0.01
    workspace_radius: float = 0.15
    max_tilt: float = 1.0

    @classmethod
    def from_config(cls, config: Mapping[str, Any]) -> Thresholds:
        return cls(**{k: float(v) for k, v in config.items()})


@dataclass(frozen=True)
class Trajectories:
    """What the classifier reads from a batch of episodes, one row per episode.

    Attributes:
      cube_pos: (n, T, 3) cube centre, m.
      cube_quat: (n, T, 4) cube orientation, w-x-y-z.
      pad_z: (n, T) height of the pads' centre (carriage z + its offset), m.
      carriage_vz: (n, T) carriage vertical velocity, m/s.
      contacts: (n, T) number of pad-cube contacts (both pads).
      phase: (T,) `Phase` of each step.
      timestep: s.
      home_xy: (2,) the gripper's x, y during the episode, m.
      healthy: (n,) False where a warning froze the episode or its state went non-finite.
    """

    cube_pos: np.ndarray
    cube_quat: np.ndarray
    pad_z: np.ndarray
    carriage_vz: np.ndarray
    contacts: np.ndarray
    phase: np.ndarray
    timestep: float
    home_xy: np.ndarray
    healthy: np.ndarray


def tilt(quat: np.ndarray) -> np.ndarray:
    """Angle (rad) between the cube's z axis and the world's, from w-x-y-z quaternions (..., 4)."""
    w, x, y, z = np.moveaxis(quat, -1, 0)
    # z-component of the rotated z axis: 1 - 2 (x^2 + y^2) for a unit quaternion.
    cos = np.clip(1.0 - 2.0 * (x * x + y * y), -1.0, 1.0)
    return np.arccos(cos)


def classify(
    traj: Trajectories, success: np.ndarray, thresholds: Thresholds
) -> dict[str, np.ndarray]:
    """Failure category of each episode (None for a success) and the hypothesis' quantities.

    Returns:
      failure_category: (n,) object array of category values (str) or None.
      peak_slip: (n,) largest downward slide of the cube along the pads after the grasp closed
        (m): cube height relative to the pads, against its value when the lift starts.
      peak_carriage_accel: (n,) largest |vertical acceleration| of the carriage during the
        lift (m/s^2).
    """
    phase = traj.phase
    lift = phase == Phase.LIFT
    hold = phase == Phase.HOLD
    lift_start = int(np.argmax(lift))
    lift_end = int(np.flatnonzero(lift)[-1])
    relative = traj.cube_pos[..., 2] - traj.pad_z
    # Slide since the lift started; positive = the cube sank along the pads.
    slide = relative[:, lift_start : lift_start + 1] - relative
    after_grasp = lift | hold
    peak_slip = np.where(after_grasp, slide, -np.inf).max(axis=1)
    accel = np.diff(traj.carriage_vz, axis=1) / traj.timestep
    peak_accel = np.abs(np.where(lift[1:], accel, 0.0)).max(axis=1)

    floor_height = traj.cube_pos[:, 0, 2]
    rose = (traj.cube_pos[..., 2] - floor_height[:, None]).max(axis=1) > thresholds.lifted_height
    drift = np.linalg.norm(traj.cube_pos[..., :2] - traj.home_xy, axis=-1)
    knocked = (drift > thresholds.workspace_radius) | (tilt(traj.cube_quat) > thresholds.max_tilt)
    # Losing the grasp: sliding down the pads, or no pad touching the cube, once lifting.
    lost = after_grasp & ((slide > thresholds.slip_distance) | (traj.contacts <= 0))

    def first(mask: np.ndarray) -> np.ndarray:
        """Step of each row's first True, or T when there is none."""
        return np.where(mask.any(axis=1), mask.argmax(axis=1), mask.shape[1])

    t_knocked, t_lost = first(knocked), first(lost)
    category = np.full(success.shape, None, dtype=object)
    for i in np.flatnonzero(~success):
        if not traj.healthy[i]:
            cat = FailureCategory.UNHEALTHY
        elif t_knocked[i] < t_lost[i]:
            # Left the workspace or tilted out before the grasp was lost: knocked or flung,
            # not a slip (a slipped cube that tumbles on landing is still a slip).
            cat = FailureCategory.KNOCKED
        elif not rose[i]:
            cat = FailureCategory.NEVER_GRASPED
        elif t_lost[i] <= lift_end:
            cat = FailureCategory.SLIPPED
        else:
            cat = FailureCategory.DROPPED
        category[i] = cat.value
    return {
        "failure_category": category,
        "peak_slip": np.nan_to_num(peak_slip, nan=np.inf),
        "peak_carriage_accel": peak_accel,
    }


def trajectories_from_batch(model: Any, batch: Any, *, phase: np.ndarray, home_xy) -> Trajectories:
    """Read a batch of `mujoco.rollout` output (an `EpisodeBatch`) as `Trajectories`."""
    physics, sensordata = batch.physics, batch.sensordata
    spec = ModelSpec.of(model)
    # Pad centre height = carriage z joint + a constant offset, read off the compiled model.
    data = mujoco.MjData(model)
    mujoco.mj_resetDataKeyframe(model, data, 0)
    mujoco.mj_kinematics(model, data)
    pad_offset = data.geom_xpos[spec.pad_geoms[0], 2] - data.qpos[spec.lift_qpos]
    left, right = spec.pad_found
    return Trajectories(
        cube_pos=physics[:, :, spec.state_cube_position],
        cube_quat=physics[:, :, spec.state_cube_quat],
        pad_z=physics[:, :, spec.state_lift_z] + pad_offset,
        carriage_vz=physics[:, :, spec.state_lift_vz],
        contacts=sensordata[:, :, left] + sensordata[:, :, right],
        phase=phase,
        timestep=float(model.opt.timestep),
        home_xy=np.asarray(home_xy, dtype=float),
        healthy=healthy(physics),
    )
