"""The report's solver line says what the compiled model's `opt` holds (checked against the
MJCF's own attributes) and the warm-start rule each kind of controller runs under."""

from __future__ import annotations

import mujoco
import numpy as np
from mujoco import rollout

from mjtrial.report.solver import solver_line, warm_start_rule
from mjtrial.task import ClosedLoop, OpenLoop

# robosuite 1.5.2's Lift sets `<option density="1.2" viscosity="2e-5"/>`: air drag
AIR = """
<mujoco>
  <option timestep="0.002" solver="CG" iterations="50" tolerance="1e-10" noslip_iterations="3"
          density="1.2" viscosity="2e-5" wind="0 0.5 0"/>
  <worldbody>
    <body><freejoint/><geom type="box" size="0.1 0.1 0.1" mass="1"/></body>
  </worldbody>
</mujoco>
"""
MANIFEST = {
    "timestep": 0.002,
    "integrator": "mjINT_EULER",
    "cone": "mjCONE_PYRAMIDAL",
    "impratio": 1,
}
CLOSED = ClosedLoop(policy=None, observations=(), timing=None)
OPEN = OpenLoop(controls=None)


def test_the_solver_line_names_the_solver_iterations_tolerance_and_the_medium():
    line = solver_line(MANIFEST, mujoco.MjModel.from_xml_string(AIR), CLOSED)
    assert "constraint solver CG, at most 50 iterations, tolerance 1e-10" in line
    assert "line search at most 50 iterations, tolerance 0.01" in line  # MuJoCo's defaults
    assert "noslip solver: 3 iterations" in line
    assert "`density` 1.2 kg/m³, `viscosity` 2e-05 Pa·s, `wind` (0, 0.5, 0) m/s" in line
    assert "warm start set to zero at each control instant" in line
    plain = solver_line(MANIFEST, mujoco.MjModel.from_xml_string("<mujoco/>"), OPEN)
    assert "constraint solver Newton, at most 100 iterations, tolerance 1e-08" in plain
    assert "medium" not in plain and "noslip" not in plain
    assert "carried from step to step" in plain


def test_the_air_drags_a_falling_box_as_the_line_says():
    """The medium is no decoration: the same box falls slower in it."""
    heights = []
    for xml in (AIR, AIR.replace('density="1.2" viscosity="2e-5" wind="0 0.5 0"', "")):
        model = mujoco.MjModel.from_xml_string(xml)
        data = mujoco.MjData(model)
        data.qvel[2] = -20.0
        mujoco.mj_step(model, data, 500)
        heights.append(data.qpos[2])
    assert heights[0] > heights[1]
    assert "medium" not in solver_line(
        MANIFEST,
        mujoco.MjModel.from_xml_string(
            AIR.replace('density="1.2" viscosity="2e-5" wind="0 0.5 0"', "")
        ),
        OPEN,
    )


def test_mujoco_rollout_zeros_the_warm_start_at_each_call():
    """What the closed-loop rule rests on: two `rollout` calls of 5 steps equal a plain loop
    that zeros `qacc_warmstart` after 5 steps, bit for bit, and differ from one that does not
    (a box resting on a plane: a contact keeps the solver busy)."""
    model = mujoco.MjModel.from_xml_string(
        '<mujoco><option solver="CG" iterations="3"/><worldbody><geom type="plane" '
        'size="1 1 .1"/><body pos="0 0 0.099"><freejoint/><geom type="box" size=".1 .1 .1"/>'
        "</body></worldbody></mujoco>"
    )
    data = mujoco.MjData(model)
    spec = mujoco.mjtState.mjSTATE_FULLPHYSICS
    start = np.empty(mujoco.mj_stateSize(model, spec))
    mujoco.mj_getState(model, data, start, spec)
    state = start
    for _ in range(2):
        physics, _ = rollout.rollout(model, data, state[None], nstep=5)
        state = physics[0, -1]
    reference = []
    for zero in (True, False):
        mujoco.mj_resetData(model, data)
        mujoco.mj_setState(model, data, start, spec)
        for k in range(10):
            if zero and k == 5:
                data.qacc_warmstart[:] = 0.0
            mujoco.mj_step(model, data)
        out = np.empty_like(start)
        mujoco.mj_getState(model, data, out, spec)
        reference.append(out)
    np.testing.assert_array_equal(state, reference[0])
    assert not np.array_equal(state, reference[1])
    assert "zero at each control instant" in warm_start_rule(CLOSED, model)
