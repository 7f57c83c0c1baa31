"""What a task's author gets wrong is said in one line, with its real cause (#27's list): a
policy answering in the wrong shape, a latency that is not a whole number of physics steps."""

from __future__ import annotations

import dataclasses

import pytest
from conftest import REPO_ROOT

from mjtrial.task import BoundTask, TaskError, load_task
from mjtrial.task.checks import run_task_code

CARTPOLE = REPO_ROOT / "tasks" / "cartpole_latency" / "task.py"


class _Answering:
    """The cart-pole's own policy, its answer passed through `how`."""

    def __init__(self, inner, how) -> None:
        self.inner, self.how = inner, how

    def reset(self, n: int) -> None:
        self.inner.reset(n)

    def __call__(self, observations):
        return self.how(self.inner(observations), observations)


def _preflight(how=None, condition=None):
    task = load_task(CARTPOLE)
    if how is not None:
        controller = task.controller
        policy = dataclasses.replace(
            controller, policy=lambda m, p: _Answering(controller.policy(m, p), how)
        )
        task = dataclasses.replace(task, controller=policy)
    run_task_code(
        BoundTask.of(task),
        {"stock": condition or {"latency": 0.0}},
        thresholds={"fall_angle": 0.5},
        allowed_privileged={},
    )


@pytest.mark.parametrize(
    ("how", "message"),
    [
        # transposed: a shape error, not "its rows depend on the batch"
        (lambda u, obs: u.T, r"policy: expected controls of shape \(4, nu\), one row per episode"),
        # columns past the declared observations: an empty answer, named as such
        (
            lambda u, obs: obs[:, 8:9],
            r"policy: expected controls of shape \(\d+, 1\), got \(\d+, 0\)",
        ),
    ],
    ids=["transposed", "columns past the observations"],
)
def test_a_policy_answering_in_the_wrong_shape_is_told_so(how, message):
    with pytest.raises(TaskError, match=message) as caught:
        _preflight(how)
    assert "depend" not in str(caught.value) and "\n" not in str(caught.value)
    assert str(caught.value).startswith(f"{CARTPOLE}: ")


def test_a_latency_between_physics_steps_is_refused_not_rounded():
    with pytest.raises(
        TaskError, match=r"timing raised ValueError: latency 0.003 s is not a whole"
    ):
        _preflight(condition={"latency": 0.003})
