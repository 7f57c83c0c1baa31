"""A scripted policy for robosuite's Lift: reach above the cube, descend, close, lift.

A function of what robosuite's env observes (`robot0_eef_pos`, the grip site; `cube_pos`) and
of the policy step's index, returning robosuite's 7-d action: the grip site's displacement in
[-1, 1] (x 0.05 m per action: OSC_POSE's output_max), no rotation, and the gripper's command
(-1 opens, +1 closes; robosuite moves the fingers' target a fifth of their range per action).
Pure numpy: it runs unchanged in robosuite's env and in a plain MuJoCo loop.

Its one free parameter, `close_steps`, is how many actions the gripper closes for, holding
still, before the lift (it goes on closing while lifting). The fingers start open (the
approach opens them), and their target crosses the cube's faces only after about five closing
actions: a short close starts a fast lift with a weak grip, and the cube may slip out.
`CONDITIONS` are the two closes a question can compare: in robosuite's env, on the 40 states
of `tests/data/robosuite_lift_reference.json` (`models/robosuite_lift/reference_runs.py`),
30/40 lifted with 3 and 14/40 with 2.
"""

from __future__ import annotations

import numpy as np

MAX_STEP = 0.05  # m per action at |a| = 1 (OSC_POSE's output_max)
ABOVE = 0.08  # m above the cube's centre, where the approach ends
GRASP_DEPTH = 0.0  # the grip site's target height relative to the cube's centre
APPROACH_STEPS = 14  # actions to get above the cube
DESCEND_STEPS = 12  # actions to descend to it
LIFT_SPEED = 0.9  # of MAX_STEP per action while lifting (0.9 m/s asked)
GAIN = 1.0  # the fraction of the remaining distance asked for per action
CONDITIONS = {"close_3": 3, "close_2": 2}  # close_steps: 150 ms and 100 ms of closing


def toward(eef_pos: np.ndarray, target: np.ndarray, limit: float = 1.0) -> np.ndarray:
    """The displacement action (in [-limit, limit]) that asks for GAIN of the way to
    `target`."""
    return np.clip(GAIN * (np.asarray(target) - eef_pos) / MAX_STEP, -limit, limit)


def action(
    step: int, eef_pos: np.ndarray, cube_pos: np.ndarray, close_steps: int
) -> np.ndarray:
    """The action at policy step `step` (0 at reset), from the grip site's and the cube's
    observed positions (world frame, m)."""
    eef_pos, cube_pos = np.asarray(eef_pos, float), np.asarray(cube_pos, float)
    out = np.zeros(7)
    if step < APPROACH_STEPS:
        out[:3] = toward(eef_pos, cube_pos + [0.0, 0.0, ABOVE])
        out[6] = -1.0
    elif step < APPROACH_STEPS + DESCEND_STEPS:
        out[:3] = toward(eef_pos, cube_pos + [0.0, 0.0, GRASP_DEPTH])
        out[6] = -1.0
    elif step < APPROACH_STEPS + DESCEND_STEPS + close_steps:
        out[6] = 1.0
    else:
        out[2] = LIFT_SPEED
        out[6] = 1.0
    return out


def episode_steps(close_steps: int, lift_steps: int = 16) -> int:
    """The policy steps of an episode: approach, descent, close, then `lift_steps` lifting."""
    return APPROACH_STEPS + DESCEND_STEPS + close_steps + lift_steps
