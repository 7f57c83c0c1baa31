"""Cart-pole balance under a push, with and without sensing latency: the closed-loop task.

Question: does 20 ms of sensing latency lower balance success under push disturbances? An LQR
controller, designed on MuJoCo's own linearization of the nominal model (`mjd_transitionFD`),
holds the pole upright from encoder readings (cart position, pole angle), velocities by finite
differences between control instants. Each episode starts tilted and turning, with a pole
mass drawn from a stated range, and the pole is pushed once, sideways, for 0.1 s.

Success: the pole within 0.25 rad of upright and the cart on the track (|x| < 1 m) at every
physics step of the episode's last second.
"""

from __future__ import annotations

import functools
from pathlib import Path

import mujoco
import numpy as np

from mjtrial.sim.closed_loop import Pushes, Timing
from mjtrial.sim.controllers import EncoderFeedback, lqr_gain
from mjtrial.sim.physics import STATE_QPOS
from mjtrial.task import (
    DISTURBANCE,
    BodyMass,
    ClosedLoop,
    Episodes,
    FailureCategory,
    JointPosition,
    JointVelocity,
    Margin,
    Measure,
    Observation,
    ProtocolParameter,
    Series,
    StateParameter,
    Task,
    Threshold,
)

# The model's elements (cartpole.xml).
CART, POLE = "cart_slide", "pole_hinge"  # joints: qpos[0], qpos[1]
POLE_BODY = "pole"
DESIGN_MODEL = Path(__file__).with_name("cartpole.xml")  # the model the LQR is designed on
# The success test: the design's metric, fixed here rather than in config.
UPRIGHT = 0.25  # rad from vertical
TRACK = 1.0  # m either side of the centre
JUDGED_OVER = 1.0  # s: the last second of the episode
# LQR weights on [x, angle, x rate, angle rate] and on the motor force.
STATE_COST = np.diag([10.0, 50.0, 1.0, 1.0])
CONTROL_COST = np.eye(1) * 0.02
# Protocol parameters that scale the LQR gain's columns, in the gain's state order: a method
# with free parameters (a tuned controller) scales the designed gain; 1.0 is the design itself.
GAIN_SCALES = ("cart_gain_scale", "angle_gain_scale", "cart_rate_gain_scale", "rate_gain_scale")
GAIN_SCALED = ("cart position", "pole angle", "cart velocity", "pole rate")


def _steps(seconds: float, model: mujoco.MjModel) -> int:
    return round(seconds / model.opt.timestep)


def _whole_steps(name: str, seconds: float, model: mujoco.MjModel) -> None:
    """Refuse a time that is not a whole number of physics steps: rounding it would run another
    latency or period than the config says, without a word."""
    if abs(_steps(seconds, model) * model.opt.timestep - seconds) > 1e-9:
        raise ValueError(
            f"{name} {seconds:g} s is not a whole number of {model.opt.timestep:g} s physics "
            "steps; expected a multiple of the timestep"
        )


def timing(model: mujoco.MjModel, params) -> Timing:
    for name in ("latency", "control_period"):
        _whole_steps(name, params[name], model)
    per_control = _steps(params["control_period"], model)
    return Timing(
        steps_per_control=per_control,
        n_controls=round(params["duration"] / params["control_period"]),
        latency_steps=_steps(params["latency"], model),
    )


@functools.cache
def design_gain(control_period: float) -> np.ndarray:
    """The LQR gain, designed once on the nominal model as committed: a simulator variant
    (another timestep or integrator) changes the plant the controller meets, not the design
    (and `mjd_transitionFD` does not linearize RK4)."""
    model = mujoco.MjModel.from_xml_path(str(DESIGN_MODEL))
    per_control = _steps(control_period, model)
    return lqr_gain(model, q=STATE_COST, r=CONTROL_COST, steps_per_control=per_control)


def policy(model: mujoco.MjModel, params) -> EncoderFeedback:
    per_control = _steps(params["control_period"], model)
    # times 1.0 is exact: with the default scales the gain is the design's, bit for bit
    scales = np.array([[params[name] for name in GAIN_SCALES]])
    return EncoderFeedback(
        design_gain(params["control_period"]) * scales,
        period=per_control * model.opt.timestep,
        ctrl_range=model.actuator_ctrlrange,
    )


def pushes(model: mujoco.MjModel, values) -> Pushes:
    """A sideways force on the pole's centre of mass for 0.1 s, from `push_time`."""
    body = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_BODY, POLE_BODY)
    start = np.round(np.asarray(values["push_time"]) / model.opt.timestep).astype(np.int64)
    wrench = np.zeros((len(start), 6))
    wrench[:, 0] = values["push_force"]
    return Pushes(body, start, start + _steps(0.1, model), wrench)


def _angles(episodes: Episodes) -> tuple[np.ndarray, np.ndarray]:
    """Cart position and pole angle, (n, n_steps) each."""
    m = episodes.model
    x = episodes.physics[
        :, :, STATE_QPOS + m.jnt_qposadr[mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_JOINT, CART)]
    ]
    angle = episodes.physics[
        :, :, STATE_QPOS + m.jnt_qposadr[mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_JOINT, POLE)]
    ]
    return x, angle


def success(episodes: Episodes) -> np.ndarray:
    x, angle = _angles(episodes)
    tail = slice(-_steps(JUDGED_OVER, episodes.model), None)
    return ((np.abs(angle[:, tail]) < UPRIGHT) & (np.abs(x[:, tail]) < TRACK)).all(axis=1)


def measure(episodes: Episodes) -> dict[str, np.ndarray]:
    x, angle = _angles(episodes)
    tail = slice(-_steps(JUDGED_OVER, episodes.model), None)

    def first(mask: np.ndarray) -> np.ndarray:
        return np.where(mask.any(axis=1), mask.argmax(axis=1), mask.shape[1])

    return {
        "peak_angle": np.abs(angle).max(axis=1),
        "peak_cart_offset": np.abs(x).max(axis=1),
        "final_angle": angle[:, -1],
        "peak_limit_fraction": np.maximum(
            np.abs(angle[:, tail]) / UPRIGHT, np.abs(x[:, tail]) / TRACK
        ).max(axis=1),
        # steps at which the cart first left the track, the pole first passed fall angles
        "_left_track_step": first(np.abs(x) >= TRACK),
        "_angles": np.abs(angle),
    }


def _fell(measures, thresholds) -> np.ndarray:
    fallen = measures["_angles"] >= thresholds["fall_angle"]
    when = np.where(fallen.any(axis=1), fallen.argmax(axis=1), fallen.shape[1])
    return (when < fallen.shape[1]) & (when <= measures["_left_track_step"])


TASK = Task(
    name="cartpole_latency",
    title="cart-pole balance under a push",
    model="cartpole.xml",
    state_parameters=(
        StateParameter("pole_angle", "rad", -0.1, 0.1, JointPosition(POLE), "initial tilt"),
        StateParameter("pole_rate", "rad/s", -0.5, 0.5, JointVelocity(POLE), "initial turn"),
        StateParameter("pole_mass", "kg", 0.05, 0.3, BodyMass(POLE_BODY), "the pole's mass"),
        StateParameter("push_force", "N", -6.0, 6.0, DISTURBANCE, "sideways push on the pole"),
        StateParameter("push_time", "s", 0.5, 1.0, DISTURBANCE, "when the push starts"),
    ),
    protocol_parameters=(
        ProtocolParameter(
            "latency",
            "s",
            0.0,
            minimum=0.0,
            maximum=0.1,
            description="sensing latency, a whole number of physics steps",
        ),
        ProtocolParameter(
            "duration", "s", 3.0, minimum=1.5, maximum=30.0, description="episode length"
        ),
        ProtocolParameter(
            "control_period",
            "s",
            0.01,
            minimum=0.0,
            maximum=0.1,
            exclusive_minimum=True,
            description="time between control instants",
        ),
        *(
            ProtocolParameter(
                name,
                "",
                1.0,
                minimum=0.2,
                maximum=3.0,
                description=f"factor on the LQR gain's {what} column (1: as designed)",
            )
            for name, what in zip(GAIN_SCALES, GAIN_SCALED, strict=True)
        ),
    ),
    controller=ClosedLoop(
        policy=policy,
        observations=("cart_position", "pole_angle"),
        timing=timing,
        pushes=pushes,
    ),
    observations=(
        Observation.joint_position("cart_position", CART, source="cart encoder"),
        Observation.joint_position("pole_angle", POLE, source="pole encoder"),
        Observation.joint_velocity("cart_velocity", CART, source=None),
        Observation.joint_velocity("pole_rate", POLE, source=None),
    ),
    series=(
        Series.joint_position("pole_angle", POLE, body=POLE_BODY, plot="pole angle (rad)"),
        Series.joint_position("cart_position", CART, body="cart", plot="cart position (m)"),
        Series.control("motor_force", "cart_motor", body="cart", plot="motor force (N)"),
    ),
    success=success,
    success_text=(
        f"the pole within {UPRIGHT:g} rad of upright and the cart on the track "
        f"(|x| < {TRACK:g} m) at every physics step of the episode's last {JUDGED_OVER:g} s"
    ),
    trace="pole_angle",
    trace_levels=(("upright limit (rad)", UPRIGHT), ("", -UPRIGHT)),
    limitations=(
        "**One plant and one controller.** A single cart-pole with one LQR design; another "
        "controller (a latency-aware one, with a predictor) may lose nothing to 20 ms.",
        "**Latency as whole physics steps.** Sensing latency is a delay of the encoder "
        "readings by a whole number of 2 ms steps, without jitter or dropped samples.",
        "**Pushes of one shape.** Each push is a 0.1 s sideways force on the pole within the "
        "stated range and window; other disturbances (impacts, noise) were not tried.",
    ),
    measure=measure,
    measures=(
        Measure("peak_angle", "rad", "largest |pole angle| over the episode"),
        Measure("peak_cart_offset", "m", "largest |cart position| over the episode"),
        Measure("final_angle", "rad", "pole angle at the end", recorded=True),
        Measure(
            "peak_limit_fraction",
            "",
            f"largest fraction of the success test's limits (|angle| / {UPRIGHT:g} rad, "
            f"|x| / {TRACK:g} m) in the last {JUDGED_OVER:g} s: a success is below 1",
            recorded=True,
        ),
    ),
    # how far below the success test's limits the judged second stayed
    margin=Margin("peak_limit_fraction", boundary=1.0, above=False),
    failure_categories=(
        FailureCategory("fell", "the pole passed fall_angle before the cart left the track", _fell),
        FailureCategory(
            "left the track",
            "the cart went past |x| = 1 m",
            lambda m, t: m["_left_track_step"] < m["_angles"].shape[1],
        ),
        FailureCategory(
            "not settled",
            "still tilted past 0.25 rad in the last second",
            lambda m, t: np.ones(len(m["_angles"]), dtype=bool),
        ),
    ),
    thresholds=(
        Threshold(
            "fall_angle",
            "rad",
            0.5,
            "the pole counts as fallen past this",
            minimum=UPRIGHT,
            maximum=3.1416,
        ),
    ),
)
