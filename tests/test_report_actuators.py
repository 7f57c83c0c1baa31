"""What the report says bounds each actuator is what MuJoCo does: every bound is checked by
driving the actuator to its extremes in MuJoCo and reading `data.actuator_force`, on models no
one here wrote (gymnasium-robotics' Fetch, dm_control's reacher) and on small models of the
kinds they lack (muscles as myosuite declares them, filters, integrators, damped servos)."""

from __future__ import annotations

import itertools
from pathlib import Path

import mujoco
import numpy as np
import pytest

from mjtrial.report.actuators import (
    activation_text,
    actuator_force_limit,
    actuator_lines,
    peak_muscle_force,
)

ROOT = Path(__file__).resolve().parents[1]
FETCH = ROOT / "tasks/fetch_pick/assets/fetch/pick_and_place.xml"
REACHER = ROOT / "tasks/reacher_goal/reacher.xml"

# An elbow moved by two muscles over a spatial tendon, as myosuite declares its muscles
# (timeconst 10 and 40 ms, ctrlrange [0, 1]); one with its peak force given, one by `scale`.
ELBOW = """
<mujoco>
  <compiler angle="radian"/>
  <option timestep="0.002"/>
  <worldbody>
    <site name="origin" pos="0 0 1.2"/>
    <body name="forearm" pos="0 0 1">
      <joint name="elbow" type="hinge" axis="0 1 0" range="-1 2"/>
      <geom type="capsule" size="0.02" fromto="0 0 0 0.3 0 0" mass="1"/>
      <site name="insertion" pos="0.1 0 0"/>
    </body>
  </worldbody>
  <tendon>
    <spatial name="flexor"><site site="origin"/><site site="insertion"/></spatial>
  </tendon>
  <actuator>
    <muscle name="strong" tendon="flexor" force="100" timeconst="0.01 0.04" ctrlrange="0.001 1"/>
    <muscle name="scaled" tendon="flexor" scale="200" timeconst="0.01 0.04" ctrlrange="0 1"/>
    <general name="filtered" joint="elbow" dyntype="filter" dynprm="0.05" gainprm="3"
             ctrlrange="-1 1"/>
    <general name="integrated" joint="elbow" dyntype="integrator" gainprm="3" ctrlrange="-1 1"
             actlimited="true" actrange="-2 2"/>
    <position name="damped" joint="elbow" kp="10" kv="2" ctrlrange="-1 1"/>
    <position name="geared" joint="elbow" kp="10" gear="2" ctrlrange="-1 1"/>
  </actuator>
  <keyframe><key name="start" act="0.5 0.25 0.1 0"/></keyframe>
</mujoco>
"""


def _index(model: mujoco.MjModel, name: str) -> int:
    return mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_ACTUATOR, name)


def _force(model: mujoco.MjModel, i: int, *, ctrl: float, q: float, act: float = 0.0, qvel=0.0):
    """MuJoCo's force of actuator `i` where it acts (gear × `data.actuator_force`) with its
    joint (or the tendon's joint) at `q`, its ctrl and activation given."""
    data = mujoco.MjData(model)
    joint = model.actuator_trnid[i, 0]
    if model.actuator_trntype[i] == mujoco.mjtTrn.mjTRN_TENDON:
        joint = 0  # the elbow, the one joint the tendon spans
    data.qpos[model.jnt_qposadr[joint]] = q
    data.qvel[model.jnt_dofadr[joint]] = qvel
    data.ctrl[i] = ctrl
    if model.actuator_actadr[i] >= 0:
        data.act[model.actuator_actadr[i]] = act
    mujoco.mj_forward(model, data)
    return model.actuator_gear[i, 0] * data.actuator_force[i]


@pytest.mark.parametrize("path", [FETCH, REACHER])
def test_stateless_bounds_are_what_mujoco_reaches_at_the_extremes(path):
    """For the suites' motors and position servos: the force at every corner of (ctrlrange,
    joint range) spans exactly the reported bounds."""
    model = mujoco.MjModel.from_xml_path(str(path))
    for i in range(model.nu):
        joint = model.actuator_trnid[i, 0]
        positions = model.jnt_range[joint] if model.jnt_limited[joint] else [0.0]
        forces = [
            _force(model, i, ctrl=c, q=q)
            for c, q in itertools.product(model.actuator_ctrlrange[i], positions)
        ]
        low, high, _ = actuator_force_limit(model, i)
        np.testing.assert_allclose([min(forces), max(forces)], [low, high], rtol=1e-12)


def test_the_fetchs_fingers_are_bounded_by_kp_times_target_minus_joint_range():
    """gymnasium-robotics' finger servos: kp 30000 N/m, target [0, 0.2] m, joint [0, 0.05] m:
    kp × [0 - 0.05, 0.2 - 0] = [-1500, 6000] N, and the joint's range stops the finger."""
    model = mujoco.MjModel.from_xml_path(str(FETCH))
    lines = actuator_lines(model)
    name = "robot0:l_gripper_finger_joint"
    assert (
        f"  - `{name}` on joint `{name}`: position servo, target [0, 0.2] m (ctrlrange), "
        "kp 30000 N/m; force [-1500, 6000] N (kp × (ctrlrange − the joint's range)); "
        "the joint's range [0, 0.05] m stops it (a soft limit)"
    ) in lines
    assert "unbounded" not in "\n".join(lines)


def test_a_muscles_bounds_are_its_peak_force_force_velocity_and_passive_force():
    model = mujoco.MjModel.from_xml_string(ELBOW)
    for name in ("strong", "scaled"):
        i = _index(model, name)
        low, high, source = actuator_force_limit(model, i)
        assert high == 0  # a muscle pulls
        grid = [
            _force(model, i, ctrl=1, q=q, act=a, qvel=v)
            for q in np.linspace(*model.jnt_range[0], 31)
            for a in (0.0, 1.0)
            for v in (-50.0, 0.0, 50.0)
        ]
        assert low <= min(grid) and max(grid) <= 0
        # the peak: optimal length, at rest, full activation; F0 × fvmax lengthening fast
        angles = np.linspace(*model.jnt_range[0], 601)
        f0 = peak_muscle_force(model, i)
        passive = [_force(model, i, ctrl=1, q=q) for q in angles]
        at_rest = [
            p - _force(model, i, ctrl=1, q=q, act=1) for p, q in zip(passive, angles, strict=True)
        ]
        assert max(at_rest) == pytest.approx(f0, rel=1e-3)  # force-length 1 at optimal length
        fast = [
            p - _force(model, i, ctrl=1, q=q, act=1, qvel=v)
            for p, q in zip(passive, angles, strict=True)
            for v in (-50.0, 50.0)
        ]
        assert max(fast) == pytest.approx(f0 * 1.2, rel=1e-3)  # lengthening fast: fvmax
        assert f"peak force {f0:g} N × force-velocity up to fvmax 1.2" in source
    assert peak_muscle_force(model, _index(model, "strong")) == 100  # its `force`
    scaled = _index(model, "scaled")  # `scale` / acc0, MuJoCo's rule for force -1
    assert peak_muscle_force(model, scaled) == pytest.approx(200 / model.actuator_acc0[scaled])
    text = "\n".join(actuator_lines(model, keyframe=0))
    assert "unbounded" not in text.split("`filtered`")[0]
    assert "`strong` on tendon `flexor`: muscle, peak force `force` 100 N" in text


def test_activation_is_said_with_its_time_constants_range_and_start():
    model = mujoco.MjModel.from_xml_string(ELBOW)
    strong = activation_text(model, _index(model, "strong"), keyframe=0)
    assert "time constants 10 ms activating, 40 ms deactivating" in strong
    assert "each episode starts from its initial state's (0.5 after the keyframe's `act`" in strong
    assert "(0 after MuJoCo's reset" in activation_text(model, _index(model, "strong"))
    filtered = activation_text(model, _index(model, "filtered"))
    assert "filter (first order, towards the ctrl), time constant 50 ms" in filtered
    integrated = activation_text(model, _index(model, "integrated"))
    assert "integrator" in integrated and "`actrange` [-2, 2]" in integrated
    assert activation_text(model, _index(model, "damped")) == ""


def test_stateful_bounds_hold_when_driven_to_the_extremes():
    """Hold the ctrl at each end for 3 s: the filter's force tends to gain × ctrl, the
    integrator's stops at gain × actrange."""
    model = mujoco.MjModel.from_xml_string(ELBOW)
    for name, expected in (("filtered", (-3, 3)), ("integrated", (-6, 6))):
        i = _index(model, name)
        assert actuator_force_limit(model, i)[:2] == expected
        reached = []
        for end in model.actuator_ctrlrange[i]:
            data = mujoco.MjData(model)
            data.ctrl[i] = end
            for _ in range(1500):  # their force is gain × activation, whatever the elbow does
                mujoco.mj_step(model, data)
            reached.append(data.actuator_force[i])
        assert min(reached) >= expected[0] and max(reached) <= expected[1]
        np.testing.assert_allclose(sorted(reached), expected, rtol=1e-6)


def test_servos_with_damping_or_a_gear_say_so():
    model = mujoco.MjModel.from_xml_string(ELBOW)
    text = "\n".join(actuator_lines(model))
    # kv × the velocity has no bound: no number is given
    damped = "`damped` on joint `elbow`: position servo, target [-1, 1] rad (ctrlrange), kp 10 "
    assert damped in text
    assert "kv 2 (damping); force unbounded (no forcerange; its bias has a velocity term" in text
    geared = _index(model, "geared")
    low, high, _ = actuator_force_limit(model, geared)
    forces = [
        _force(model, geared, ctrl=c, q=q)
        for c, q in itertools.product(model.actuator_ctrlrange[geared], model.jnt_range[0])
    ]
    np.testing.assert_allclose([min(forces), max(forces)], [low, high], rtol=1e-12)
    assert "(kp × (ctrlrange − gear × the joint's range), × gear 2)" in text


def test_a_tendons_limited_joints_are_what_stops_it():
    """The gantry's gripper: one servo on a fixed tendon over the two finger joints, each
    declared `range="0 0.05"` in the MJCF; the line names those ranges."""
    from mjtrial.sim.physics import load_model

    mjcf = (ROOT / "models/gantry_gripper/gantry_gripper.xml").read_text()
    for finger, axis in (("left_finger", "0 1 0"), ("right_finger", "0 -1 0")):
        assert f'<joint name="{finger}" class="gantry" axis="{axis}" range="0 0.05"/>' in mjcf
    model = load_model(ROOT / "models/gantry_gripper/scene.xml")
    line = actuator_lines(model)[1 + _index(model, "gripper")]
    assert line.endswith(
        "its joints' ranges stop it (soft limits): `left_finger` [0, 0.05] m, "
        "`right_finger` [0, 0.05] m"
    )


def test_a_muscles_passive_force_at_lmax_is_mujocos_curve():
    """MuJoCo's passive curve (engine_util_misc.c): a cubic from optimal length to b = (1 +
    lmax) / 2 reaching fpmax / 2, then a line of slope fpmax / (b - 1): at lmax, 1.5 × fpmax,
    not fpmax."""
    from mjtrial.report.actuators import passive_at_lmax

    for lmax, fpmax in ((1.6, 1.3), (1.90307, 1.37875)):
        prm = np.array([0.75, 1.05, 100.0, 200.0, 0.5, lmax, 1.5, fpmax, 1.2])
        assert passive_at_lmax(prm) == pytest.approx(1.5 * fpmax, rel=1e-12)
    model = mujoco.MjModel.from_xml_string(ELBOW)
    assert "1.95 × peak at `lmax` (`fpmax` 1.3)" in actuator_lines(model)[1]
