"""Grasp and lift on a gantry gripper with an imperfect grasp: the built-in open-loop task.

Question: does a slower lift raise grasp-and-lift success when the grasp is imperfect? Each
state puts the cube off the gripper's axis (dx, dy), turned (yaw) and with its own mass; the
open-loop protocol descends, closes, lifts over `lift_time` and holds. Success: the cube's
centre above 0.2 m at the end of the hold.

The protocol's timings (`protocol.py`), the model's element names (`model_spec.py`), the
failure taxonomy (`taxonomy.py`) and a literal `mj_step` reference stepper (`simulate.py`) live
beside this file, which states the experiment through the task interface; its episodes equal
the reference's bit for bit (tests/test_task_gantry.py).
"""

from __future__ import annotations

import dataclasses

import mujoco
import numpy as np

from mjtrial.sim.physics import ModelError
from mjtrial.task import (
    FAILURE_CATEGORY,
    NONFINITE,
    STEPS_SIMULATED,
    WARNING,
    BodyMass,
    Custom,
    Episodes,
    FailureCategory,
    JointPosition,
    Margin,
    Measure,
    OpenLoop,
    ProtocolParameter,
    Series,
    StateParameter,
    Task,
    Threshold,
)

from . import taxonomy
from .model_spec import ModelSpec
from .protocol import (
    CONDITION_PARAMETERS,
    PROTOCOL,
    Phase,
    condition_protocol,
    control_sequence,
    episode_steps,
    hold_durations,
    hold_steps,
)
from .simulate import yaw_quaternion

CUBE = "cube"  # the cube's body and its free joint


def _set_yaw(model: mujoco.MjModel, data: mujoco.MjData, yaw: float) -> None:
    adr = ModelSpec.of(model).cube_qpos
    data.qpos[adr + 3 : adr + 7] = yaw_quaternion(yaw)


def _protocol(params):
    return condition_protocol({k: params[k] for k in CONDITION_PARAMETERS})


def controls(model: mujoco.MjModel, params) -> np.ndarray:
    ctrl, _ = control_sequence(
        params["lift_time"], timestep=model.opt.timestep, protocol=_protocol(params)
    )
    return ctrl


def phase_times(model: mujoco.MjModel, params) -> dict[str, float]:
    """When the grasp closes, the lift starts and the lift ends, s: marked on the traces."""
    timestep = model.opt.timestep
    _, phase = control_sequence(params["lift_time"], timestep=timestep, protocol=_protocol(params))
    lift = np.flatnonzero(phase == Phase.LIFT)
    return {
        "close": float(np.flatnonzero(phase == Phase.CLOSE)[0] * timestep),
        "lift": float(lift[0] * timestep),
        "lift end": float((lift[-1] + 1) * timestep),
    }


def n_steps(model: mujoco.MjModel, params) -> int:
    return episode_steps(
        params["lift_time"], timestep=model.opt.timestep, protocol=_protocol(params)
    )


def check_condition(model: mujoco.MjModel, params):
    """The protocol's control step and every hold must last at least one physics step."""
    dt = model.opt.timestep
    protocol = _protocol(params)
    if dt > protocol.segment_time:
        yield (
            "timestep",
            (
                f"timestep {dt:g} s; expected at most {protocol.segment_time:g} s, the protocol's "
                "control step"
            ),
        )
        return
    for what, seconds in hold_durations(params["lift_time"], protocol).items():
        if hold_steps(seconds, dt) < 1:
            yield what, f"a {what} of {seconds:g} s is 0 steps of {dt:g} s; expected at least one"


def check_model(model: mujoco.MjModel) -> None:
    """The elements the protocol, the taxonomy and the series read (`ModelSpec`)."""
    try:
        ModelSpec.of(model)
    except ModelError as err:
        raise ValueError(str(err).removeprefix("model: ")) from None


def success(episodes: Episodes) -> np.ndarray:
    height = episodes.physics[:, -1, ModelSpec.of(episodes.model).state_cube_z]
    return height > _protocol(episodes.params).success_height


def measure(episodes: Episodes) -> dict[str, np.ndarray]:
    """The table's columns, and when each way of failing first happened (for the categories)."""
    model, params = episodes.model, episodes.params
    protocol = _protocol(params)
    spec = ModelSpec.of(model)
    final = episodes.physics[:, -1, :]
    _, phase = control_sequence(params["lift_time"], timestep=model.opt.timestep, protocol=protocol)
    batch = dataclasses.make_dataclass("Batch", ["physics", "sensordata"])(
        episodes.physics, episodes.sensordata
    )
    traj = taxonomy.trajectories_from_batch(
        model, batch, phase=phase, home_xy=(protocol.home_x, 0.0)
    )
    # the peaks do not depend on the thresholds or the outcome
    peaks = taxonomy.classify(traj, np.ones(len(final), dtype=bool), taxonomy.Thresholds())
    return {
        "peak_slip": peaks["peak_slip"],
        "peak_carriage_accel": peaks["peak_carriage_accel"],
        "final_height": final[:, spec.state_cube_z],
        "final_x": final[:, spec.state_cube_position.start],
        "final_y": final[:, spec.state_cube_position.start + 1],
        "_trajectories": traj,
    }


def _classified(measures, thresholds) -> np.ndarray:
    """The package's taxonomy, every episode classified as if it failed."""
    traj = measures["_trajectories"]
    fails = np.zeros(len(traj.healthy), dtype=bool)
    return taxonomy.classify(
        dataclasses.replace(traj, healthy=np.ones_like(traj.healthy)),
        fails,
        thresholds_of(thresholds),
    )


def thresholds_of(thresholds) -> taxonomy.Thresholds:
    return taxonomy.Thresholds(**{k: float(v) for k, v in thresholds.items()})


def _category(value: str):
    return lambda measures, thresholds: (
        _classified(measures, thresholds)["failure_category"] == value
    )


HOLDS = {
    "settle_time": "hold before the descent",
    "pre_close_time": "hold at the bottom before closing",
    "close_time": "hold while the gripper closes",
    "hold_time": "hold after the lift, before success is judged",
}
LIFT_PLOT = "cube height, finger opening, ctrl (m)"
FORCE_PLOT = "pad-cube normal force (N)"


def _from_spec(read):
    """A series' read from the gantry's resolved elements: `read(spec, rows, sensors, ctrl)`."""

    def bind(model):
        spec = ModelSpec.of(model)
        return lambda rows, sensors, ctrl: read(spec, rows, sensors, ctrl)

    return bind


def _pad_force(side: int):
    return _from_spec(lambda spec, r, s, c: np.abs(s[:, spec.pad_normal_forces[side]]))


SERIES = (
    Series(
        "cube_height", CUBE, LIFT_PLOT, _from_spec(lambda spec, r, s, c: r[:, spec.state_cube_z])
    ),
    Series(
        "finger_opening",
        "carriage",
        LIFT_PLOT,
        _from_spec(lambda spec, r, s, c: r[:, list(spec.state_fingers)].mean(axis=1)),
    ),
    *(
        Series.control(f"ctrl_{actuator}", actuator, body="carriage", plot=LIFT_PLOT)
        for actuator in ("x", "y", "z", "gripper")
    ),
    Series("left_normal_force", "left_finger", FORCE_PLOT, _pad_force(0)),
    Series("right_normal_force", "right_finger", FORCE_PLOT, _pad_force(1)),
)

THRESHOLD_DEFAULTS = {f.name: f.default for f in dataclasses.fields(taxonomy.Thresholds)}

TASK = Task(
    name="gantry_lift",
    title="grasp and lift on a gantry gripper",
    model="../../models/gantry_gripper/scene.xml",
    keyframe=0,
    state_parameters=(
        StateParameter("dx", "m", -0.018, 0.018, JointPosition(CUBE, 0), "cube offset along x"),
        StateParameter("dy", "m", -0.012, 0.012, JointPosition(CUBE, 1), "cube offset along y"),
        StateParameter("yaw", "rad", -0.6, 0.6, Custom(_set_yaw), "cube yaw about z"),
        StateParameter("mass", "kg", 0.05, 0.6, BodyMass(CUBE), "cube mass", nominal=0.3),
    ),
    protocol_parameters=(
        ProtocolParameter(
            "lift_time",
            "s",
            0.15,
            minimum=0.0,
            exclusive_minimum=True,
            # an episode's whole trajectory is held in memory while its batch is simulated, and
            # 10 s keeps a batch of 64 episodes near 100 MB
            maximum=10.0,
            description="duration of the lift",
            required=True,
        ),
        *(
            ProtocolParameter(
                name,
                "s",
                getattr(PROTOCOL, name),
                minimum=0.0,
                exclusive_minimum=True,
                maximum=10.0,
                description=description,
            )
            for name, description in HOLDS.items()
        ),
        ProtocolParameter(
            "gripper_closed",
            "m",
            PROTOCOL.gripper_closed,
            minimum=0.0,
            maximum=0.04,
            description="mean finger opening target when closed (the fingers open to 0.04 m)",
        ),
    ),
    controller=OpenLoop(controls, n_steps=n_steps),
    check_condition=check_condition,
    check_model=check_model,
    series=SERIES,
    trace="cube_height",
    trace_marks=phase_times,
    trace_levels=(("success height (m)", PROTOCOL.success_height),),
    success=success,
    # the cube's final height above the success height: the closest calls and, at the other
    # end, the highest cubes (one still in flight would pass the test)
    margin=Margin("final_height", boundary=lambda params: _protocol(params).success_height),
    success_text=(
        f"the cube's centre is above {PROTOCOL.success_height:g} m at the end of the hold after "
        f"the lift ({PROTOCOL.hold_time:g} s unless a condition sets hold_time)"
    ),
    nominal_text="no offset, no yaw, mass as compiled",
    limitations=(
        "**One model.** A single gantry gripper with one pad geometry, grip force limit and "
        "contact parametrisation; another gripper may trade speed for success differently.",
        "**Open-loop protocol.** The lift follows a fixed control sequence with no feedback; a "
        "controller that reacts to slip could close the gap between the conditions.",
        "**Mass-only randomization.** The cube's mass varies while its inertia stays as "
        "compiled, and size, friction and shape are fixed; the result is about this "
        "distribution of offsets, yaws and masses only.",
        "**Only the lift durations that ran.** The comparison says nothing about durations in "
        "between (the dose-response study sweeps them), nor about a real robot.",
    ),
    measure=measure,
    measures=(
        Measure("final_height", "m", "the cube's centre height at the end", recorded=True),
        Measure("final_x", "m", "the cube's centre x at the end"),
        Measure("final_y", "m", "the cube's centre y at the end"),
        STEPS_SIMULATED,
        NONFINITE,
        WARNING,
        FAILURE_CATEGORY,
        Measure("peak_slip", "m", "the cube's largest slide down the pads after the grasp"),
        Measure("peak_carriage_accel", "m/s^2", "the carriage's largest vertical acceleration"),
    ),
    failure_categories=tuple(
        FailureCategory(c.value, c.value, _category(c.value))
        for c in taxonomy.FailureCategory
        if c is not taxonomy.FailureCategory.UNHEALTHY
    ),
    thresholds=(
        Threshold(
            "lifted_height",
            "m",
            THRESHOLD_DEFAULTS["lifted_height"],
            "rise that counts as lifted (at most the 0.33 m lift)",
            minimum=0.0,
            exclusive_minimum=True,
            maximum=0.33,
        ),
        Threshold(
            "slip_distance",
            "m",
            THRESHOLD_DEFAULTS["slip_distance"],
            "slide down the pads that loses the grasp (at most the 4 cm cube)",
            minimum=0.0,
            exclusive_minimum=True,
            maximum=0.04,
        ),
        Threshold(
            "workspace_radius",
            "m",
            THRESHOLD_DEFAULTS["workspace_radius"],
            "distance from the gripper axis that counts as flung (at most the 5 m floor drawn)",
            minimum=0.0,
            exclusive_minimum=True,
            maximum=5.0,
        ),
        Threshold(
            "max_tilt",
            "rad",
            THRESHOLD_DEFAULTS["max_tilt"],
            "tilt that counts as rotated out of the grasp",
            minimum=0.0,
            exclusive_minimum=True,
            maximum=3.1416,
        ),
    ),
)
