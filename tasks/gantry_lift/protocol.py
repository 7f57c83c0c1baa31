"""The episode protocol: one place for every timing, target and threshold of a lift.

The protocol is open loop, so an episode's whole control sequence is known before it starts;
`control_sequence` builds it, and both the reference stepper and the rollout engine follow it.
Times are simulated seconds; "hold t" means stepping with ctrl unchanged for round(t / timestep)
steps.
"""

from __future__ import annotations

import enum
from collections.abc import Mapping
from dataclasses import dataclass, replace

import numpy as np

# Actuator order in the model: ctrl = [x, y, z, gripper opening].
CTRL_X, CTRL_Y, CTRL_Z, CTRL_GRIPPER = range(4)
N_CTRL = 4


class Phase(enum.IntEnum):
    """Protocol phases, in order; each control step belongs to exactly one."""

    SETTLE = 0
    DESCEND = 1
    PRE_CLOSE = 2
    CLOSE = 3
    LIFT = 4
    HOLD = 5


@dataclass(frozen=True)
class Protocol:
    """Timings and targets of the grasp-and-lift episode, in the order `control_sequence` uses them.

    Attributes:
      home_x: gantry x target above the cube's nominal position, m.
      cube_z: the cube centre's starting height, m.
      gripper_open, gripper_closed: mean finger opening targets, m.
      z_down, z_up: carriage (gantry_z) targets at the bottom and at home, m.
      settle_time, pre_close_time, close_time, hold_time: durations of the holds, s.
      descend_segments: set-points of the descent, each held for `segment_time` s.
      segment_time: duration of one descent or lift set-point, s.
      success_height: height the cube's centre must exceed at the end of the hold, m.
    """

    home_x: float = 0.12
    cube_z: float = 0.02
    gripper_open: float = 0.04
    gripper_closed: float = 0.0
    z_down: float = -0.33
    z_up: float = 0.0
    settle_time: float = 0.3
    descend_segments: int = 100
    segment_time: float = 0.01
    pre_close_time: float = 0.3
    close_time: float = 0.6
    hold_time: float = 0.5
    success_height: float = 0.2

    def lift_segments(self, lift_time: float) -> int:
        """Number of lift set-points: one per 10 ms, at least one."""
        return max(1, round(lift_time / self.segment_time))


PROTOCOL = Protocol()

# What a condition may set besides its lift time: the holds' durations and the grip target.
# Never the success height (the metric is fixed by the design), nor the geometry of the task.
CONDITION_PARAMETERS = (
    "settle_time",
    "pre_close_time",
    "close_time",
    "hold_time",
    "gripper_closed",
)


def condition_protocol(condition: Mapping[str, float]) -> Protocol:
    """The protocol of one condition: `PROTOCOL` with the condition's parameters set.

    Args:
      condition: the condition's config, `lift_time` and any of `CONDITION_PARAMETERS`.
    """
    unknown = set(condition) - {"lift_time", *CONDITION_PARAMETERS}
    if unknown:
        raise ValueError(
            f"condition parameter(s) {sorted(unknown)}: expected lift_time or one of "
            f"{list(CONDITION_PARAMETERS)}"
        )
    return replace(PROTOCOL, **{k: float(v) for k, v in condition.items() if k != "lift_time"})


def hold_steps(duration: float, timestep: float) -> int:
    """Steps that make up a hold of `duration` seconds."""
    return round(duration / timestep)


def hold_durations(lift_time: float, protocol: Protocol = PROTOCOL) -> dict[str, float]:
    """Every hold of an episode by the parameter that sets it, s (one descent or lift set-point
    for the segments): each must last at least one physics step."""
    return {
        "settle_time": protocol.settle_time,
        "descend segment": protocol.segment_time,
        "pre_close_time": protocol.pre_close_time,
        "close_time": protocol.close_time,
        "lift_time": lift_time / protocol.lift_segments(lift_time),
        "hold_time": protocol.hold_time,
    }


def episode_steps(lift_time: float, *, timestep: float, protocol: Protocol = PROTOCOL) -> int:
    """Physics steps of an episode: the length of `control_sequence`, without building it."""
    p, holds = protocol, hold_durations(lift_time, protocol)
    segments = {"descend segment": p.descend_segments, "lift_time": p.lift_segments(lift_time)}
    return sum(segments.get(k, 1) * hold_steps(v, timestep) for k, v in holds.items())


def control_sequence(
    lift_time: float, *, timestep: float, protocol: Protocol = PROTOCOL
) -> tuple[np.ndarray, np.ndarray]:
    """Open-loop controls of one episode, one row per physics step.

    Args:
      lift_time: duration of the lift, seconds (> 0).
      timestep: the model's timestep, seconds.
      protocol: timings and targets.

    Returns:
      ctrl: (n_steps, 4) float64, the ctrl applied before each step.
      phase: (n_steps,) int8, the `Phase` of each step.
    """
    if not lift_time > 0:
        raise ValueError(f"lift_time: expected a positive number of seconds, got {lift_time!r}")
    p = protocol
    rows: list[np.ndarray] = []
    phases: list[np.ndarray] = []
    ctrl = np.array([p.home_x, 0.0, p.z_up, p.gripper_open])

    def hold(duration: float, phase: Phase) -> None:
        n = hold_steps(duration, timestep)
        rows.append(np.tile(ctrl, (n, 1)))
        phases.append(np.full(n, phase, dtype=np.int8))

    hold(p.settle_time, Phase.SETTLE)
    for k in range(p.descend_segments):
        ctrl[CTRL_Z] = p.z_down * (k + 1) / p.descend_segments
        hold(p.segment_time, Phase.DESCEND)
    hold(p.pre_close_time, Phase.PRE_CLOSE)
    ctrl[CTRL_GRIPPER] = p.gripper_closed
    hold(p.close_time, Phase.CLOSE)
    n_lift = p.lift_segments(lift_time)
    for k in range(n_lift):
        ctrl[CTRL_Z] = p.z_down + (p.z_up - p.z_down) * (k + 1) / n_lift
        hold(lift_time / n_lift, Phase.LIFT)
    hold(p.hold_time, Phase.HOLD)
    return np.concatenate(rows), np.concatenate(phases)
