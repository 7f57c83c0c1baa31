"""The control sequence follows the protocol's timings literally."""

from __future__ import annotations

import numpy as np
import pytest
from gantry_lift.protocol import CTRL_GRIPPER, CTRL_Z, Phase, control_sequence


@pytest.mark.parametrize(("lift_time", "lift_steps"), [(0.15, 75), (1.5, 750), (0.004, 2)])
def test_step_counts_per_phase(lift_time, lift_steps):
    ctrl, phase = control_sequence(lift_time, timestep=0.002)
    counts = np.bincount(phase, minlength=len(Phase))
    # settle 0.3 s, descend 100 x 0.01 s, wait 0.3 s, close 0.6 s, lift, hold 0.5 s at 2 ms
    assert counts.tolist() == [150, 500, 150, 300, lift_steps, 250]
    assert ctrl.shape == (len(phase), 4)
    assert np.all(np.diff(phase) >= 0)


def test_targets():
    ctrl, phase = control_sequence(0.15, timestep=0.002)
    assert np.all(ctrl[phase == Phase.SETTLE] == [0.12, 0, 0, 0.04])
    descend = ctrl[phase == Phase.DESCEND, CTRL_Z]
    # 100 set-points, 5 steps each: the k-th is -0.33 (k+1)/100.
    np.testing.assert_allclose(descend[::5], -0.33 * np.arange(1, 101) / 100)
    assert np.all(ctrl[phase == Phase.CLOSE, CTRL_GRIPPER] == 0)
    lift = ctrl[phase == Phase.LIFT, CTRL_Z]
    np.testing.assert_allclose(lift[::5], -0.33 + 0.33 * np.arange(1, 16) / 15)
    assert np.all(ctrl[phase == Phase.HOLD, CTRL_Z] == 0)


def test_rejects_nonpositive_lift_time():
    with pytest.raises(ValueError, match="lift_time"):
        control_sequence(0.0, timestep=0.002)


@pytest.mark.parametrize("lift_time", [0.0123, 0.15, 0.3, 1.5])
@pytest.mark.parametrize("timestep", [0.0003, 0.001, 0.002])
def test_episode_steps_is_the_control_sequence_length(lift_time, timestep):
    from gantry_lift.protocol import episode_steps

    ctrl, _ = control_sequence(lift_time, timestep=timestep)
    assert episode_steps(lift_time, timestep=timestep) == len(ctrl)
