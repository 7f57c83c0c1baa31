"""A goal that lives in no model element (a target angle, a commanded velocity) is a state
parameter applied to nothing (`GOAL`): allowed when an observation the policy reads, the
success test or a measure reads it, refused in one line when nothing does (issue 41, item 8)."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
from conftest import REPO_ROOT

from mjtrial.task import GOAL, BoundTask, Episodes, StateParameter, TaskError, load_task
from mjtrial.task.checks import read_by_task, run_task_code

SHORT = {"fast": {"latency": 0.0, "duration": 1.5}}
CARTPOLE_THRESHOLDS = {"fall_angle": 0.5}


def _thresholds(task) -> dict[str, float]:
    return {t.name: t.default for t in task.thresholds}


def test_a_goal_the_policy_observes_needs_no_model_element():
    """dm_control's reacher with its goal moved out of the model: the target geom stays where
    it was compiled, the policy reads the goal as an observation and success reads it too."""
    reacher = load_task("tasks/reacher_goal/task.py", repo_root=REPO_ROOT)
    goals = {"goal_x", "goal_y"}
    task = replace(
        reacher,
        state_parameters=tuple(
            replace(p, apply=GOAL) if p.name in goals else p for p in reacher.state_parameters
        ),
    )
    assert read_by_task(task, None) == goals  # the policy's observations alone
    run_task_code(
        BoundTask.of(task),
        {"as_shipped": {"latency": 0.02}},
        thresholds=_thresholds(task),
        allowed_privileged={},
    )


def _cartpole_with_setpoint(*, success_reads_it: bool):
    cartpole = load_task("tasks/cartpole_latency/task.py", repo_root=REPO_ROOT)
    setpoint = StateParameter("setpoint", "m", -0.1, 0.1, GOAL, "where the cart should be")
    judged = cartpole.success

    def success(episodes: Episodes) -> np.ndarray:  # near the commanded place, and upright
        x = episodes.physics[:, -1, 1]  # time, then the cart's slide
        return judged(episodes) & (np.abs(x - episodes.values["setpoint"]) < 0.5)

    return replace(
        cartpole,
        state_parameters=(*cartpole.state_parameters, setpoint),
        success=success if success_reads_it else judged,
    )


def test_a_goal_only_the_success_test_reads_is_allowed():
    task = _cartpole_with_setpoint(success_reads_it=True)
    run_task_code(BoundTask.of(task), SHORT, thresholds=CARTPOLE_THRESHOLDS)


def test_a_goal_nothing_reads_is_refused_in_one_line():
    task = _cartpole_with_setpoint(success_reads_it=False)
    with pytest.raises(TaskError) as err:
        run_task_code(BoundTask.of(task), SHORT, thresholds=CARTPOLE_THRESHOLDS)
    assert str(err.value).endswith(
        "state parameter 'setpoint': the episode is the same at its low and high values and "
        "nothing reads it; expected its apply (Goal) to change the initial state, the model or "
        "a push, or an observation the policy reads, success or a measure to read it (a goal)"
    )
