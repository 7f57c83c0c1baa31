"""The report's description of a model is true of any model: checked against MuJoCo itself
(its collision detection on overlapping geoms) and against limits worked out by hand."""

from __future__ import annotations

import mujoco
import pytest

from mjtrial.report.model import (
    actuator_force_limit,
    actuator_lines,
    collision_pairs,
    contact_lines,
    joint_lines,
)

# Every geom a 5 cm sphere at the origin, so every pair MuJoCo's filter lets through touches.
BODIES = """
  <worldbody>
    <geom name="ground" type="sphere" size="0.05"/>
    <body name="fixture"><geom name="fixture" type="sphere" size="0.05"/></body>
    <body name="arm">
      <freejoint/>
      <geom name="arm" type="sphere" size="0.05"/>
      <geom name="arm_visual" type="sphere" size="0.05" contype="0" conaffinity="0"/>
      <body name="hand">
        <joint name="wrist" type="hinge" axis="0 0 1"/>
        <geom name="hand" type="sphere" size="0.05"/>
        <body name="finger"><geom name="finger" type="sphere" size="0.05"/></body>
      </body>
    </body>
    <body name="box"><freejoint/><geom name="box" type="sphere" size="0.05"/></body>
    <body name="ghost"><freejoint/>
      <geom name="ghost" type="sphere" size="0.05" contype="2" conaffinity="2"/></body>
    <body name="probe"><freejoint/>
      <geom name="probe" type="sphere" size="0.05" contype="4" conaffinity="1"/></body>
  </worldbody>
  <contact>
    <exclude body1="arm" body2="box"/>
    <pair geom1="ghost" geom2="arm_visual"/>
  </contact>
"""


def _model(option: str = "") -> mujoco.MjModel:
    return mujoco.MjModel.from_xml_string(f"<mujoco>{option}{BODIES}</mujoco>")


def _mujoco_contacts(model: mujoco.MjModel) -> list[tuple[int, int]]:
    data = mujoco.MjData(model)
    mujoco.mj_forward(model, data)
    return sorted({tuple(sorted(map(int, c.geom))) for c in data.contact[: data.ncon]})


@pytest.mark.parametrize(
    "option",
    ["", '<option><flag filterparent="disable"/></option>'],
    ids=["default", "filterparent off"],
)
def test_the_pairs_that_can_collide_are_those_mujoco_finds_touching(option):
    model = _model(option)
    expected = _mujoco_contacts(model)
    assert len(expected) > 5  # the model exercises the filter, not an empty case
    assert collision_pairs(model) == expected


def test_the_filter_cases_by_name():
    model = _model()
    names = {
        frozenset(mujoco.mj_id2name(model, mujoco.mjtObj.mjOBJ_GEOM, g) for g in pair)
        for pair in collision_pairs(model)
    }
    assert frozenset({"ground", "fixture"}) not in names  # both welded to the world
    assert frozenset({"arm", "hand"}) not in names  # parent and child
    assert frozenset({"arm", "finger"}) not in names  # finger is welded to hand, arm's child
    assert frozenset({"arm", "box"}) not in names  # excluded
    assert frozenset({"arm", "ghost"}) not in names  # contype 2 against conaffinity 1
    assert frozenset({"ghost", "arm_visual"}) in names  # an explicit pair
    assert frozenset({"probe", "box"}) in names  # contype 1 of box meets conaffinity 1 of probe


def test_no_contact_is_reported_where_the_option_disables_contacts():
    model = _model('<option><flag contact="disable"/></option>')
    assert _mujoco_contacts(model) == [] == collision_pairs(model)
    assert contact_lines(model) == [
        "- Contacts: disabled in the model's `<option>`; no geom collides."
    ]


ACTUATED = """
<mujoco>
  <worldbody>
    <body name="link"><joint name="shoulder" type="hinge"/>
      <geom type="capsule" size="0.02" fromto="0 0 0 0.3 0 0"/>
      <body name="slider" pos="0.3 0 0">
        <joint name="rail" type="slide" damping="2" frictionloss="0.5"/>
        <geom type="box" size="0.02 0.02 0.02"/>
        <site name="tip"/>
      </body>
    </body>
  </worldbody>
  <tendon>
    <fixed name="both"><joint joint="shoulder" coef="1"/><joint joint="rail" coef="1"/></fixed>
  </tendon>
  <actuator>
    <motor name="shoulder_motor" joint="shoulder" gear="30" ctrlrange="-1 1"/>
    <motor name="wrist_like" joint="shoulder" gear="7" ctrlrange="-1 1"/>
    <motor name="rail_motor" joint="rail" ctrlrange="-10 10" forcerange="-5 5"/>
    <motor name="free_motor" joint="rail" ctrllimited="false"/>
    <position name="servo" joint="rail" kp="100" ctrlrange="-0.1 0.1"/>
    <general name="tendon_drive" tendon="both" gainprm="4" ctrlrange="0 2" gear="-3"/>
  </actuator>
</mujoco>
"""


def test_actuator_limits_in_the_units_of_what_they_drive():
    model = mujoco.MjModel.from_xml_string(ACTUATED)
    limit = {
        mujoco.mj_id2name(model, mujoco.mjtObj.mjOBJ_ACTUATOR, i): actuator_force_limit(model, i)
        for i in range(model.nu)
    }
    assert limit["shoulder_motor"][:2] == (-30, 30)  # ctrlrange x gear, N·m
    assert limit["wrist_like"][:2] == (-7, 7)
    assert limit["rail_motor"][:2] == (-5, 5)  # forcerange bounds the gain x ctrlrange of 10
    assert limit["free_motor"] is None
    assert limit["servo"] is None  # a position servo without forcerange
    assert limit["tendon_drive"][:2] == (-24, 0)  # 4 x [0, 2], then gear -3
    lines = "\n".join(actuator_lines(model))
    assert "`shoulder_motor` on joint `shoulder`: [-30, 30] N·m" in lines
    assert "`rail_motor` on joint `rail`: [-5, 5] N" in lines
    assert "`tendon_drive` on tendon `both`: [-24, 0] N" in lines
    assert "`servo` on joint `rail`: unbounded" in lines


def test_joint_damping_armature_and_frictionloss_are_listed():
    model = mujoco.MjModel.from_xml_string(ACTUATED)
    text = "\n".join(joint_lines(model))
    assert "| `rail` | slide | 2 | 0 | 0.5 |" in text
    assert "the other joint has none" in text and "`shoulder`" not in text


def test_the_development_states_use_is_the_designs_own_words():
    from mjtrial.report.text import _development_use

    said = {"design": {"development_split": "Gains were tuned on the development states."}}
    assert _development_use(said) == ' (the design: "Gains were tuned on the development states")'
    assert "calibrate" not in _development_use({"design": {}})
