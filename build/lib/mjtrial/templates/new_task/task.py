"""new_task: push a block along a rail to a target line, written by `mjtrial new-task`.

Question (replace it with yours): does a firm, short push bring the block to the target more
often than a gentle, long one of the same impulse? Each state draws the block's mass and its
start; each condition sets the push's force and duration; success is the block's centre within
`TOLERANCE` of the target at the end of the episode.

Everything the experiment needs is declared in `TASK` at the bottom; the comments marked CHANGE
say what to edit for your own experiment. The README's "Write your own task" walks through it.
"""

from __future__ import annotations

import mujoco
import numpy as np

from mjtrial.task import (
    BodyMass,
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

# CHANGE: the model's elements this file reads (model.xml beside it).
BLOCK, SLIDE, PUSHER = "block", "block_slide", "pusher"
# CHANGE: the success test, fixed here as the design's metric.
TARGET = 0.5  # m: where the block should stop
TOLERANCE = 0.05  # m either side of it
DURATION = 3.0  # s: the episode's length


def controls(model: mujoco.MjModel, params) -> np.ndarray:
    """CHANGE: the control applied before each physics step, (n_steps, nu), for a condition's
    protocol parameters: here the push's force for its duration, then nothing."""
    n_steps = round(DURATION / model.opt.timestep)
    ctrl = np.zeros((n_steps, model.nu))
    pusher = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_ACTUATOR, PUSHER)
    ctrl[: round(params["push_time"] / model.opt.timestep), pusher] = params["push_force"]
    return ctrl


def _position(episodes: Episodes) -> np.ndarray:
    """The block's position along the rail at every step, (n_episodes, n_steps)."""
    model = episodes.model
    adr = model.jnt_qposadr[mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_JOINT, SLIDE)]
    # Rows are mjSTATE_FULLPHYSICS: time, then qpos.
    return episodes.physics[:, :, 1 + adr]


def success(episodes: Episodes) -> np.ndarray:
    """CHANGE: one boolean per episode."""
    return np.abs(_position(episodes)[:, -1] - TARGET) < TOLERANCE


def measure(episodes: Episodes) -> dict[str, np.ndarray]:
    """CHANGE: every `Measure` by name (a column of the rollout table), plus anything the
    failure categories read."""
    x = _position(episodes)
    return {
        "final_position": x[:, -1],
        "peak_position": x.max(axis=1),
        "distance_from_line": np.abs(x[:, -1] - TARGET),
    }


TASK = Task(
    name="new_task",
    title="a block pushed to a line",  # CHANGE: a noun phrase for the report
    model="model.xml",  # relative to this file
    # CHANGE: the randomized initial state; the states table's columns, drawn in this order.
    state_parameters=(
        StateParameter("mass", "kg", 0.5, 3.0, BodyMass(BLOCK), "the block's mass"),
        StateParameter("start", "m", -0.05, 0.05, JointPosition(SLIDE), "the block's start"),
    ),
    # CHANGE: what conditions, sweeps and variants may set, with bounds (the config's schema).
    protocol_parameters=(
        ProtocolParameter("push_force", "N", 1.0, minimum=0.0, maximum=10.0, required=True),
        ProtocolParameter(
            "push_time",
            "s",
            1.0,
            minimum=0.0,
            maximum=DURATION,
            exclusive_minimum=True,
            required=True,
        ),
    ),
    controller=OpenLoop(controls),
    success=success,
    success_text=f"the block's centre within {TOLERANCE:g} m of the line at {TARGET:g} m "
    f"at the end of the {DURATION:g} s episode",
    measure=measure,
    measures=(
        Measure("final_position", "m", "where the block ends", recorded=True),
        Measure("peak_position", "m", "the block's furthest point"),
        Measure("distance_from_line", "m", "how far from the line the block ends"),
    ),
    # CHANGE: how far an episode was from failing its success test (positive: a success), from
    # one of the measures: here the tolerance less the distance from the line. A benchmark
    # replays the successes of smallest margin and the episodes of largest.
    margin=Margin("distance_from_line", boundary=TOLERANCE, above=False),
    # CHANGE: failure categories, first match wins; each test reads the measures and thresholds.
    failure_categories=(
        FailureCategory(
            "overshot",
            "passed the line by more than the tolerance",
            lambda m, t: m["final_position"] > TARGET + TOLERANCE,
        ),
        FailureCategory(
            "stopped short",
            "ended more than the threshold short of the line",
            lambda m, t: m["final_position"] < TARGET - t["short_by"],
        ),
        FailureCategory(
            "near miss",
            "short of the line, within the threshold",
            lambda m, t: m["final_position"] < TARGET,
        ),
    ),
    thresholds=(
        Threshold("short_by", "m", 0.2, "a stop this far short is 'stopped short'", minimum=0.0),
    ),
    # CHANGE: the series each recording plots beside the 3D scene; the first is the report's trace.
    series=(
        Series.joint_position("position", SLIDE, body=BLOCK, plot="block position (m)"),
        Series.control("push", PUSHER, body=BLOCK, plot="push force (N)"),
    ),
    trace_levels=(("target (m)", TARGET),),
    limitations=(
        "**A template.** This experiment is the scaffold's example; replace it with yours.",
    ),
)
