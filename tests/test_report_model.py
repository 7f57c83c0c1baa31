"""The report's description of a model is true of any model: checked against MuJoCo itself
(its collision detection on overlapping geoms) and against limits worked out by hand."""

from __future__ import annotations

from pathlib import Path

import mujoco
import pytest

from mjtrial.report.actuators import actuator_force_limit, actuator_lines
from mjtrial.report.model import (
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
    <body name="handle" mocap="true"><geom name="handle" type="sphere" size="0.05"/>
      <body name="handle_tip"><geom name="handle_tip" type="sphere" size="0.05"/></body>
    </body>
    <body name="pointer" mocap="true"><geom name="pointer" type="sphere" size="0.05"/></body>
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
    # two dof-less weld bodies (the world's, mocap bodies) are never tested against each other
    assert frozenset({"ground", "handle"}) not in names
    assert frozenset({"handle", "pointer"}) not in names
    assert frozenset({"handle_tip", "pointer"}) not in names
    assert frozenset({"handle", "box"}) in names  # a mocap body pushes a free body


FETCH = Path(__file__).resolve().parents[1] / "tasks/fetch_pick/assets/fetch/pick_and_place.xml"


def _documented_pairs(model: mujoco.MjModel) -> list[tuple[int, int]]:
    """MuJoCo's documented collision filter, worked out from the body tree alone (not from
    `body_weldid`): a body's weld body is its first ancestor-or-self with a joint or a mocap
    flag (else the world); pairs on one weld body, on two weld bodies without joints, on a weld
    body and its parent's (filterparent; never the world), on an `<exclude>`d body pair, or
    whose contype and conaffinity do not match are out; explicit `<pair>`s are in; none when
    `<option>` disables contacts."""

    off = mujoco.mjtDisableBit.mjDSBL_CONTACT | mujoco.mjtDisableBit.mjDSBL_CONSTRAINT
    if model.opt.disableflags & off:
        return []

    def weld_of(body: int) -> int:
        while body and not model.body_jntnum[body] and model.body_mocapid[body] < 0:
            body = int(model.body_parentid[body])
        return body

    parent_off = model.opt.disableflags & mujoco.mjtDisableBit.mjDSBL_FILTERPARENT
    excluded = {
        frozenset((int(a), int(b)))
        for a, b in zip(
            model.exclude_signature >> 16, model.exclude_signature & 0xFFFF, strict=True
        )
    }
    explicit = zip(model.pair_geom1, model.pair_geom2, strict=True)
    found = {tuple(sorted((int(a), int(b)))) for a, b in explicit}
    for g1 in range(model.ngeom):
        for g2 in range(g1 + 1, model.ngeom):
            t1, a1 = model.geom_contype[g1], model.geom_conaffinity[g1]
            t2, a2 = model.geom_contype[g2], model.geom_conaffinity[g2]
            if not ((t1 & a2) or (t2 & a1)):
                continue
            b1, b2 = int(model.geom_bodyid[g1]), int(model.geom_bodyid[g2])
            w1, w2 = weld_of(b1), weld_of(b2)
            if w1 == w2 or (not model.body_jntnum[w1] and not model.body_jntnum[w2]):
                continue
            p1, p2 = weld_of(int(model.body_parentid[w1])), weld_of(int(model.body_parentid[w2]))
            if not parent_off and w1 and w2 and (w1 == p2 or w2 == p1):
                continue
            if frozenset((b1, b2)) in excluded:
                continue
            found.add((g1, g2))
    return sorted(found)


@pytest.mark.parametrize(
    "option",
    ["", '<option><flag filterparent="disable"/></option>'],
    ids=["default", "filterparent off"],
)
def test_the_pairs_that_can_collide_follow_the_documented_rules(option):
    model = _model(option)
    assert collision_pairs(model) == _documented_pairs(model)


def _fetch_spheres() -> mujoco.MjModel:
    """The Fetch with every geom a 5 cm sphere and every body at its parent's origin, its weld
    to the mocap body off: every pair MuJoCo's filter lets through touches."""
    spec = mujoco.MjSpec.from_file(str(FETCH))
    for geom in spec.geoms:
        geom.type = mujoco.mjtGeom.mjGEOM_SPHERE
        geom.size = [0.05, 0, 0]
        geom.pos = [0, 0, 0]
        geom.meshname = ""
    for body in spec.bodies[1:]:
        body.pos = [0, 0, 0]
    for equality in spec.equalities:
        equality.active = False
    return spec.compile()


def test_the_fetchs_pairs_are_those_mujoco_finds_touching_and_the_documented_rules():
    model = mujoco.MjModel.from_xml_path(str(FETCH))
    pairs = collision_pairs(model)
    assert pairs == _documented_pairs(model)
    spheres = _fetch_spheres()
    assert _mujoco_contacts(spheres) == collision_pairs(spheres) == pairs
    geom = lambda g: mujoco.mj_id2name(model, mujoco.mjtObj.mjOBJ_GEOM, g)  # noqa: E731
    named = {frozenset(map(geom, p)) for p in pairs}
    # the two fingers are excluded from each other, and the torso from the shoulder
    assert frozenset({"robot0:r_gripper_finger_link", "robot0:l_gripper_finger_link"}) not in named
    text = "\n".join(contact_lines(model))
    assert f"- Contacts: {len(pairs)} geom pairs pass MuJoCo's collision filter" in text


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
    <position name="geared_servo" joint="shoulder" kp="50" gear="2" ctrlrange="-1 0.5"
              forcerange="-3 4"/>
    <velocity name="spinner" joint="shoulder" kv="5" ctrlrange="-2 2"/>
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
    assert limit["geared_servo"][:2] == (-6, 8)  # forcerange x gear
    assert limit["tendon_drive"][:2] == (-24, 0)  # 4 x [0, 2], then gear -3
    lines = "\n".join(actuator_lines(model))
    assert "`shoulder_motor` on joint `shoulder`: force [-30, 30] N·m" in lines
    assert "`rail_motor` on joint `rail`: force [-5, 5] N" in lines
    assert "`tendon_drive` on tendon `both`: force [-24, 0] N" in lines
    # a servo's control is a target: ctrlrange / gear in the joint's units
    assert (
        "`servo` on joint `rail`: position servo, target [-0.1, 0.1] m (ctrlrange), kp 100 N/m; "
        "force unbounded" in lines
    )
    assert (
        "`geared_servo` on joint `shoulder`: position servo, target [-0.5, 0.25] rad "
        "(ctrlrange / gear 2), kp 50 (200 N·m/rad at the joint: kp × gear²); force [-6, 8] N·m "
        "(forcerange, × gear 2)" in lines
    )
    assert "`spinner` on joint `shoulder`: velocity servo, target [-2, 2] rad/s" in lines
    assert "`free_motor` on joint `rail`: force unbounded (no forcerange, no control" in lines


def test_joint_damping_armature_and_frictionloss_are_listed():
    model = mujoco.MjModel.from_xml_string(ACTUATED)
    text = "\n".join(joint_lines(model))
    assert "| `rail` | slide | 2 | 0 | 0.5 |" in text
    assert "the other joint has none" in text and "`shoulder`" not in text


def test_the_development_states_use_is_the_designs_own_words():
    from mjtrial.report.setup import _development_use

    said = {"design": {"development_split": "Gains were tuned on the development states."}}
    assert _development_use(said) == ' (the design: "Gains were tuned on the development states")'
    assert "calibrate" not in _development_use({"design": {}})
