"""Reach a goal drawn per episode with DeepMind Control Suite's planar reacher, as shipped.

Question: does 60 ms of sensing latency lower how often a joint-space PD controller brings the
fingertip onto a goal drawn anew each episode? The goal is the model's own `target` geom, moved
per episode (`ModelValue`: its x and y); the controller is told the goal (an episode value, as
a robot is commanded one), solves the two-link inverse kinematics for it and drives each joint
with PD from its encoder, rates by finite differences between control instants.

Success: the fingertip within the target's radius of the goal at every physics step of the
episode's last half second. Nothing is added to the model (`README.md` beside it).
"""

from __future__ import annotations

import mujoco
import numpy as np

from mjtrial.sim.closed_loop import Timing
from mjtrial.sim.physics import STATE_QPOS
from mjtrial.task import (
    ClosedLoop,
    Episodes,
    FailureCategory,
    JointPosition,
    Margin,
    Measure,
    ModelValue,
    Observation,
    ProtocolParameter,
    Series,
    StateParameter,
    Task,
)

# The model's elements (reacher.xml): two hinges, qpos[0] and qpos[1], and the goal's geom.
SHOULDER, WRIST = "shoulder", "wrist"
HAND, FINGER, TARGET = "hand", "finger", "target"
JUDGED_OVER = 0.5  # s: the end of the episode over which the fingertip must stay on the goal
TOLERANCE = 0.05  # m: the target geom's radius as shipped (dm_control's "big target")
KD_RATIO = 0.12  # s: derivative gain as a fraction of the proportional one


def _steps(seconds: float, model: mujoco.MjModel) -> int:
    return round(seconds / model.opt.timestep)


def timing(model: mujoco.MjModel, params) -> Timing:
    steps = _steps(params["latency"], model)
    if abs(steps * model.opt.timestep - params["latency"]) > 1e-9:
        raise ValueError(
            f"latency {params['latency']:g} s is not a whole number of {model.opt.timestep:g} s "
            "physics steps"
        )
    return Timing(
        steps_per_control=_steps(params["control_period"], model),
        n_controls=round(params["duration"] / params["control_period"]),
        latency_steps=steps,
    )


def link_lengths(model: mujoco.MjModel) -> tuple[float, float]:
    """Upper arm (shoulder to wrist) and forearm (wrist to fingertip), from the model."""
    hand = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_BODY, HAND)
    finger = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_BODY, FINGER)
    return float(model.body_pos[hand, 0]), float(model.body_pos[finger, 0])


def inverse_kinematics(
    x: np.ndarray, y: np.ndarray, lengths: tuple[float, float], wrist_sign: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Joint angles that put the fingertip on (x, y), the goal clipped to the reachable annulus;
    `wrist_sign` chooses the elbow (the side the wrist is already bent to)."""
    l1, l2 = lengths
    r = np.clip(np.hypot(x, y), abs(l1 - l2) + 1e-6, l1 + l2 - 1e-6)
    cos_wrist = (r**2 - l1**2 - l2**2) / (2 * l1 * l2)
    wrist = wrist_sign * np.arccos(np.clip(cos_wrist, -1.0, 1.0))
    shoulder = np.arctan2(y, x) - np.arctan2(l2 * np.sin(wrist), l1 + l2 * np.cos(wrist))
    return shoulder, wrist


class JointPD:
    """Inverse kinematics to the commanded goal, then PD on each joint from its encoder (rates
    by finite differences), torques clipped to the motors' range. Row by row and elementwise:
    an episode's command never depends on its batch."""

    def __init__(self, model: mujoco.MjModel, kp: float, period: float) -> None:
        self.lengths = link_lengths(model)
        self.kp, self.kd, self.period = kp, kp * KD_RATIO, period
        self.gear = model.actuator_gear[:, 0].copy()
        self.previous = None

    def reset(self, n_episodes: int) -> None:
        self.previous = None

    def __call__(self, observations: np.ndarray) -> np.ndarray:
        angles, goal = observations[:, 0:2], observations[:, 2:4]
        previous = angles if self.previous is None else self.previous
        self.previous = angles.copy()
        rates = (angles - previous) / self.period
        sign = np.where(angles[:, 1] < 0, -1.0, 1.0)
        target = np.stack(inverse_kinematics(goal[:, 0], goal[:, 1], self.lengths, sign), axis=1)
        error = np.angle(np.exp(1j * (target - angles)))  # wrapped to (-pi, pi]
        torque = self.kp * error - self.kd * rates
        return np.clip(torque / self.gear, -1.0, 1.0)


def fingertip(episodes: Episodes) -> np.ndarray:
    """The fingertip's (x, y) at every step, (n, n_steps, 2), by forward kinematics."""
    l1, l2 = link_lengths(episodes.model)
    q = episodes.physics[:, :, STATE_QPOS : STATE_QPOS + 2]
    shoulder, elbow = q[..., 0], q[..., 0] + q[..., 1]
    x = l1 * np.cos(shoulder) + l2 * np.cos(elbow)
    y = l1 * np.sin(shoulder) + l2 * np.sin(elbow)
    return np.stack([x, y], axis=-1)


def _distance(episodes: Episodes) -> np.ndarray:
    goal = np.stack([episodes.values["goal_x"], episodes.values["goal_y"]], axis=1)
    return np.linalg.norm(fingertip(episodes) - goal[:, None, :], axis=-1)


def _judged(episodes: Episodes) -> np.ndarray:
    return _distance(episodes)[:, -_steps(JUDGED_OVER, episodes.model) :]


def success(episodes: Episodes) -> np.ndarray:
    return (_judged(episodes) < TOLERANCE).all(axis=1)


def measure(episodes: Episodes) -> dict[str, np.ndarray]:
    judged = _judged(episodes)
    goal = np.hypot(episodes.values["goal_x"], episodes.values["goal_y"])
    return {
        "final_distance": judged[:, -1],
        "worst_distance": judged.max(axis=1),
        "goal_radius": goal,
        # the margin: how far inside the tolerance the worst judged step stayed (m)
        "tolerance_left": TOLERANCE - judged.max(axis=1),
    }


TASK = Task(
    name="reacher_goal",
    title="a planar reacher brought onto a goal drawn per episode",
    model="reacher.xml",
    state_parameters=(
        StateParameter("goal_x", "m", -0.2, 0.2, ModelValue("geom", TARGET, "pos", 0), "goal x"),
        StateParameter("goal_y", "m", -0.2, 0.2, ModelValue("geom", TARGET, "pos", 1), "goal y"),
        StateParameter("shoulder_start", "rad", -3.1, 3.1, JointPosition(SHOULDER), "start"),
        StateParameter("wrist_start", "rad", -2.5, 2.5, JointPosition(WRIST), "start"),
    ),
    protocol_parameters=(
        ProtocolParameter("latency", "s", 0.0, minimum=0.0, maximum=0.2),
        ProtocolParameter("kp", "N m/rad", 0.2, minimum=0.0, maximum=10.0),
        ProtocolParameter("control_period", "s", 0.02, minimum=0.02, maximum=0.1),
        ProtocolParameter("duration", "s", 3.0, minimum=1.0, maximum=20.0),
    ),
    controller=ClosedLoop(
        policy=lambda model, params: JointPD(model, params["kp"], params["control_period"]),
        observations=("shoulder_angle", "wrist_angle", "goal_x", "goal_y"),
        timing=timing,
    ),
    observations=(
        Observation.joint_position("shoulder_angle", SHOULDER, source="joint encoder"),
        Observation.joint_position("wrist_angle", WRIST, source="joint encoder"),
        Observation.episode_value("goal_x", "goal_x", source="the goal the robot is commanded"),
        Observation.episode_value("goal_y", "goal_y", source="the goal the robot is commanded"),
    ),
    success=success,
    success_text=(
        f"the fingertip within {TOLERANCE:g} m of the goal at every step of the last "
        f"{JUDGED_OVER:g} s"
    ),
    measure=measure,
    measures=(
        Measure("final_distance", "m", "fingertip to goal at the end", recorded=True),
        Measure("worst_distance", "m", "the largest distance over the judged time"),
        Measure("goal_radius", "m", "the goal's distance from the shoulder"),
        Measure("tolerance_left", "m", "the tolerance less the worst judged distance"),
    ),
    margin=Margin("tolerance_left", 0.0, above=True),
    failure_categories=(
        FailureCategory(
            "never arrived",
            "the fingertip ended outside the goal",
            lambda m, t: m["final_distance"] >= TOLERANCE,
        ),
        FailureCategory(
            "did not settle",
            "on the goal at the end, but not over the whole judged time",
            lambda m, t: m["worst_distance"] >= TOLERANCE,
        ),
    ),
    series=(
        Series.joint_position("shoulder", SHOULDER, body="arm", plot="joint angles (rad)"),
        Series.joint_position("wrist", WRIST, body="hand", plot="joint angles (rad)"),
        Series.control("shoulder_torque", SHOULDER, body="arm", plot="motor commands (-1..1)"),
        Series.control("wrist_torque", WRIST, body="hand", plot="motor commands (-1..1)"),
    ),
    limitations=(
        "One controller design (joint-space PD to an inverse-kinematics solution); a "
        "Cartesian or learned controller may tolerate latency differently.",
        "The goal is known exactly (an episode value); goal-sensing noise is not modelled.",
    ),
)
