"""The failure classifier on trajectories built by hand, one per category."""

from __future__ import annotations

import numpy as np
import pytest
from gantry_lift.protocol import Phase
from gantry_lift.taxonomy import FailureCategory, Thresholds, Trajectories, classify, tilt

DT = 0.01
# A short protocol: 10 steps before the lift (settle..close), 10 of lift, 10 of hold.
PHASE = np.array([Phase.CLOSE] * 10 + [Phase.LIFT] * 10 + [Phase.HOLD] * 10, dtype=np.int8)
T = PHASE.size
PAD_Z = np.concatenate([np.full(10, 0.02), np.linspace(0.053, 0.35, 10), np.full(10, 0.35)])
IDENTITY = np.array([1.0, 0, 0, 0])


def episode(*, cube_z, contacts=None, xy=(0.12, 0.0), quat=None, healthy=True):
    """One episode's arrays: cube height per step, everything else nominal unless given."""
    cube_pos = np.zeros((T, 3))
    cube_pos[:, 0], cube_pos[:, 1] = xy[0], xy[1]
    cube_pos[:, 2] = cube_z
    q = np.tile(IDENTITY, (T, 1)) if quat is None else quat
    c = np.full(T, 8.0) if contacts is None else contacts
    return cube_pos, q, c, healthy


def batch(*episodes):
    return Trajectories(
        cube_pos=np.stack([e[0] for e in episodes]),
        cube_quat=np.stack([e[1] for e in episodes]),
        pad_z=np.tile(PAD_Z, (len(episodes), 1)),
        carriage_vz=np.tile(np.gradient(PAD_Z, DT), (len(episodes), 1)),
        contacts=np.stack([e[2] for e in episodes]),
        phase=PHASE,
        timestep=DT,
        home_xy=np.array([0.12, 0.0]),
        healthy=np.array([e[3] for e in episodes]),
    )


held = PAD_Z.copy()  # the cube moves with the pads
slipped = held.copy()
slipped[14:] = 0.02  # falls back to the floor in the middle of the lift
dropped = held.copy()
dropped[24:] = 0.02  # falls during the hold
never = np.full(T, 0.02)  # never leaves the floor
no_contact = np.full(T, 8.0)
no_contact[20:] = 0  # the cube still rides along, but no pad touches it from the hold on


def test_each_category_by_hand():
    flung = episode(cube_z=held)
    flung[0][:, 0] = 0.12 + np.where(np.arange(T) >= 15, 0.3, 0.0)  # 0.3 m off mid-lift
    tumbling = np.tile(IDENTITY, (T, 1))
    tumbling[12:] = [np.cos(0.7), np.sin(0.7), 0, 0]  # tilted 1.4 rad while still held
    cases = [
        (episode(cube_z=held), True, None),
        (episode(cube_z=never), False, FailureCategory.NEVER_GRASPED),
        (episode(cube_z=slipped), False, FailureCategory.SLIPPED),
        (episode(cube_z=dropped), False, FailureCategory.DROPPED),
        (episode(cube_z=held, contacts=no_contact), False, FailureCategory.DROPPED),
        (flung, False, FailureCategory.KNOCKED),
        (episode(cube_z=held, quat=tumbling), False, FailureCategory.KNOCKED),
        (episode(cube_z=held, healthy=False), False, FailureCategory.UNHEALTHY),
    ]
    traj = batch(*(c[0] for c in cases))
    success = np.array([c[1] for c in cases])
    out = classify(traj, success, Thresholds())
    expected = [None if c[2] is None else c[2].value for c in cases]
    assert out["failure_category"].tolist() == expected


def test_slip_then_tumble_is_a_slip_not_a_knock():
    z = slipped.copy()
    quat = np.tile(IDENTITY, (T, 1))
    quat[16:] = [np.cos(0.8), 0, np.sin(0.8), 0]  # lands and tumbles after slipping
    out = classify(batch(episode(cube_z=z, quat=quat)), np.array([False]), Thresholds())
    assert out["failure_category"][0] == FailureCategory.SLIPPED.value


def test_peak_slip_and_carriage_acceleration():
    z = held.copy()
    z[12:20] -= 0.004  # a 4 mm slide that does not lose the cube
    out = classify(batch(episode(cube_z=z)), np.array([True]), Thresholds())
    assert out["peak_slip"][0] == pytest.approx(0.004)
    assert out["failure_category"][0] is None
    vz = np.gradient(PAD_Z, DT)
    lift_accel = np.abs(np.diff(vz) / DT)[PHASE[1:] == Phase.LIFT].max()
    assert out["peak_carriage_accel"][0] == pytest.approx(lift_accel)


def test_thresholds_move_the_boundary():
    z = held.copy()
    z[12:] -= 0.006  # a 6 mm slide during the lift, then still held up high but failed
    failed = np.array([False])
    loose = classify(batch(episode(cube_z=z)), failed, Thresholds(slip_distance=0.005))
    tight = classify(batch(episode(cube_z=z)), failed, Thresholds(slip_distance=0.01))
    assert loose["failure_category"][0] == FailureCategory.SLIPPED.value
    assert tight["failure_category"][0] == FailureCategory.DROPPED.value


def test_tilt_of_known_rotations():
    half = np.pi / 4  # 90 degrees about x
    q = np.array([[1, 0, 0, 0], [np.cos(half), np.sin(half), 0, 0], [0, 1, 0, 0], [0, 0, 0, 1]])
    np.testing.assert_allclose(tilt(q), [0, np.pi / 2, np.pi, 0], atol=1e-12)
