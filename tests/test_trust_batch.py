"""The fourth hostile survey, a policy that depends on its batch late in an episode: only after
control instant 25, only in batches of more than 8 rows, only for some states. The rollout's
check replayed the first 20 instants, in halves of the batch and its first row alone, and let
it through. Each test failed before its fix."""

from __future__ import annotations

import mujoco
import numpy as np
import pytest
from mujoco import rollout
from test_closed_loop import STEPS_PER_CONTROL, _episodes, _policy, encoders

from mjtrial.sim.closed_loop import PolicyError, Timing, check_replayed, run_batch

LATE = 25  # the first control instant at which the policy below may depend on its batch


class LateBatchDependence:
    """The LQR, but after control instant 25, in a batch of more than 8 rows, a row whose cart
    is right of the centre gets 1e-3 N more: nothing of it shows before instant 26, in a batch
    of 8 or fewer, or for a cart left of the centre."""

    def __init__(self, honest) -> None:
        self.honest, self.instant = honest, 0

    def reset(self, n_episodes: int) -> None:
        self.honest.reset(n_episodes)
        self.instant = 0

    def __call__(self, observations: np.ndarray) -> np.ndarray:
        controls = np.array(self.honest(observations), dtype=np.float64)
        if self.instant > LATE and len(observations) > 8:
            controls[observations[:, 0] > 0] += 1e-3
        self.instant += 1
        return controls


def _rollout(policy, n: int, n_controls: int):
    model = mujoco.MjModel.from_xml_path(str(_policy.__globals__["CARTPOLE"]))
    models, initial, pushes = _episodes(model, n)
    with rollout.Rollout(nthread=0) as runner:
        return run_batch(
            models,
            initial,
            policy,
            encoders,
            Timing(STEPS_PER_CONTROL, n_controls, 10),
            runner=runner,
            datas=[mujoco.MjData(models[0])],
            pushes=pushes,
        )


def test_a_batch_dependence_after_instant_25_is_refused_by_the_rollout():
    """Survey case 3: 16 episodes of 60 control instants; the dependence begins at 26."""
    nominal = mujoco.MjModel.from_xml_path(str(_policy.__globals__["CARTPOLE"]))
    with pytest.raises(PolicyError, match=r"batch dependence: .* control instant (\d+)") as err:
        _rollout(LateBatchDependence(_policy(nominal)), 16, 60)
    assert int(err.value.args[0].split("control instant ")[1].split()[0]) > LATE
    # In batches of 8 it depends on nothing, and passes.
    _rollout(LateBatchDependence(_policy(nominal)), 8, 60)


def test_every_row_is_replayed_alone_at_every_instant():
    """A row's dependence on its batch shows when it runs alone, the reference's batch of one
    (verify re-simulates each episode alone), at any instant of the episode."""
    rng = np.random.default_rng(2)
    observations = rng.normal(size=(12, 40, 2))
    nominal = mujoco.MjModel.from_xml_path(str(_policy.__globals__["CARTPOLE"]))
    policy = LateBatchDependence(_policy(nominal))
    policy.reset(12)
    controls = np.stack([policy(observations[:, k]) for k in range(40)], axis=1)
    row = int(np.flatnonzero(observations[:, LATE + 1, 0] > 0)[0])
    with pytest.raises(
        PolicyError,
        match=rf"batch dependence: episode row {row} of a batch of 12 gets other controls at "
        rf"control instant {LATE + 1} when it runs alone",
    ):
        check_replayed(policy, observations, controls)
