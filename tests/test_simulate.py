"""The pipeline's engine (mujoco.rollout) equals the literal mj_step reference, exactly."""

from __future__ import annotations

import numpy as np
import pytest
from gantry_lift.simulate import (
    InitialState,
    episode_outcomes,
    iter_episode_batches,
    reference_episode,
)

LIFT_TIMES = {"fast": 0.15, "slow": 1.5}


def _sample(states):
    """A spread of evaluation states: the first ones, lightest, heaviest, extreme offsets."""
    mass = np.array([s.mass for s in states])
    dx = np.array([s.dx for s in states])
    picks = {*range(6), int(mass.argmin()), int(mass.argmax()), int(dx.argmin()), int(dx.argmax())}
    return [states[i] for i in sorted(picks)]


@pytest.mark.parametrize("condition", sorted(LIFT_TIMES))
def test_engine_equals_reference_stepper(gantry_model, evaluation_states, condition):
    sample = _sample(evaluation_states)
    lift_time = LIFT_TIMES[condition]
    batches = list(
        iter_episode_batches(gantry_model, sample, lift_time=lift_time, nthread=2, batch_size=4)
    )
    physics = np.concatenate([b.physics for b in batches])
    outcomes = [episode_outcomes(gantry_model, b, lift_time=lift_time) for b in batches]
    success = np.concatenate([o["success"] for o in outcomes])
    for i, state in enumerate(sample):
        reference, warnings = reference_episode(gantry_model, state, lift_time=lift_time)
        assert not warnings.any()
        # Every step's full physics state, bit for bit: outcomes and final states follow.
        np.testing.assert_array_equal(physics[i], reference)
        # the cube's free joint is qpos[5:12]; its height is qpos[7] (state index 1 + 7)
        assert success[i] == (reference[-1, 8] > 0.2)


def test_results_do_not_depend_on_batch_size_or_threads(gantry_model, evaluation_states):
    sample = evaluation_states[:5]
    runs = [
        np.concatenate(
            [
                b.physics[:, -1]
                for b in iter_episode_batches(
                    gantry_model, sample, lift_time=0.15, nthread=n, batch_size=bs
                )
            ]
        )
        for n, bs in [(1, 5), (2, 2), (2, 1)]
    ]
    np.testing.assert_array_equal(runs[0], runs[1])
    np.testing.assert_array_equal(runs[0], runs[2])


def test_sample_has_both_outcomes(gantry_model, evaluation_states):
    """The equality test above is only meaningful if the sample holds successes and failures."""
    sample = _sample(evaluation_states)
    batch = next(
        iter_episode_batches(gantry_model, sample, lift_time=0.15, nthread=2, batch_size=64)
    )
    success = episode_outcomes(gantry_model, batch, lift_time=0.15)["success"]
    assert success.any() and not success.all()


def test_unhealthy_episode_is_a_failure_with_its_warning(gantry_model, tmp_path, monkeypatch):
    """A diverging simulation is recorded as a failure naming the warning, not a crash."""
    import copy

    monkeypatch.chdir(tmp_path)  # MuJoCo writes MUJOCO_LOG.TXT into the working directory
    model = copy.copy(gantry_model)
    # An absurd z servo gain, unlimited: the first descent set-point blows up the acceleration.
    model.actuator_gainprm[2, 0] = 1e10
    model.actuator_biasprm[2, 1] = -1e10
    model.actuator_forcerange[2] = [-1e12, 1e12]
    state = InitialState(0, 0.0, 0.0, 0.0, 0.3)
    batch = next(iter_episode_batches(model, [state], lift_time=0.15, nthread=1))
    out = episode_outcomes(model, batch, lift_time=0.15)
    assert not out["success"][0]
    assert out["warning"][0] == "mjWARN_BADQACC"
    # It ran until the first descent set-point (after the 0.3 s settle), then froze.
    assert 150 < out["steps_simulated"][0] < 160


def test_outcome_columns_do_not_hold_the_batch_trajectories(gantry_model, evaluation_states):
    """A job keeps every batch's outcome columns; a view would keep every trajectory alive."""
    [batch] = iter_episode_batches(gantry_model, evaluation_states[:3], lift_time=0.15, nthread=1)
    outcome = episode_outcomes(gantry_model, batch, lift_time=0.15)
    for name, column in outcome.items():
        if isinstance(column, np.ndarray) and column.dtype != object:
            assert not np.shares_memory(column, batch.physics), name
