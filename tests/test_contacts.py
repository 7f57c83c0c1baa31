"""The contact parameters mjtrial says each geom pair takes are those MuJoCo puts on its
contacts: every case checked against `mj_forward`'s own `data.contact` (friction, condim,
solref, solimp, the margin it includes), on small models and on the Fetch as it ships."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import mujoco
import numpy as np
import pytest
import yaml
from conftest import REPO_ROOT

from mjtrial.report.setup import _contact_edit_lines
from mjtrial.sim.contacts import (
    collision_pairs,
    contact_digest_values,
    contact_lines,
    describe_contact_changes,
    pair_contacts,
)
from mjtrial.sim.physics import load_model
from mjtrial.task import ModelValue, StateParameter, load_task

FETCH = Path(__file__).resolve().parents[1] / "tasks/fetch_pick/assets/fetch/pick_and_place.xml"


def _two_spheres(a: str, b: str, contact: str = "", option: str = "") -> mujoco.MjModel:
    """Two overlapping spheres, `a` on a free body and `b` fixed, with the given attributes."""
    return mujoco.MjModel.from_xml_string(
        f"""<mujoco>{option}<worldbody>
          <geom name="b" type="sphere" size="0.05" {b}/>
          <body><freejoint/><geom name="a" type="sphere" size="0.05" {a}/></body>
        </worldbody><contact>{contact}</contact></mujoco>"""
    )


def _contacts_as_mujoco_makes_them(model: mujoco.MjModel) -> dict[tuple[int, int], tuple]:
    data = mujoco.MjData(model)
    mujoco.mj_forward(model, data)
    assert data.ncon, "the model makes no contact: the test would check nothing"
    out = {}
    for c in data.contact[: data.ncon]:
        out[tuple(sorted(map(int, c.geom)))] = (
            int(c.dim),
            tuple(c.friction),
            tuple(c.solref),
            tuple(c.solimp),
            float(c.adhesion),
            float(c.includemargin),
            tuple(c.solreffriction),
        )
    return out


def _said(model: mujoco.MjModel) -> dict[tuple[int, int], tuple]:
    return {
        p.geoms: (p.condim, p.friction, p.solref, p.solimp, p.adhesion, p.margin, p.solreffriction)
        for p in pair_contacts(model)
    }


CASES = {
    "same priority: max friction and condim, solmix 1:1": (
        'friction="0.5 0.01 0.001" condim="3"',
        'friction="2 0.002 0.003" condim="4"',
    ),
    "solmix 3:1 weights solref and solimp": (
        'solmix="3" solref="0.01 1" solimp="0.8 0.9 0.002 0.4 3"',
        'solmix="1" solref="0.04 0.5" solimp="0.95 0.99 0.001 0.5 2"',
    ),
    "solmix 0 on one side: the other's values": (
        'solmix="0" solref="0.01 1" solimp="0.8 0.9 0.002 0.4 3"',
        'solmix="2" solref="0.04 0.5" solimp="0.95 0.99 0.001 0.5 2"',
    ),
    "solmix 0 on both sides: half and half": (
        'solmix="0" solref="0.01 1" solimp="0.8 0.9 0.002 0.4 3"',
        'solmix="0" solref="0.04 0.5" solimp="0.95 0.99 0.001 0.5 2"',
    ),
    "a direct solref: the smaller of each number": (
        'solref="-1000 -10" solmix="5"',
        'solref="0.02 1" solmix="1"',
    ),
    "higher priority wins everything but the gap": (
        'priority="1" friction="0.3 0.01 0.001" condim="1" solref="0.05 2" margin="0.01" gap="0"',
        'friction="2 0.1 0.1" condim="6" solref="0.01 1" margin="0.02" gap="0.005"',
    ),
    "the other side's higher priority": (
        'friction="0.3 0.01 0.001" condim="6" solimp="0.7 0.8 0.003 0.5 2"',
        'priority="2" friction="1.5 0.02 0.0001" condim="4"',
    ),
    "margin and gap: the sums, whatever the priorities": (
        'margin="0.003" gap="0.001" priority="1"',
        'margin="0.001" gap="0.002"',
    ),
    "adhesion: the sum": ('adhesion="3"', 'adhesion="1.5"'),
    "adhesion: the higher priority's": ('adhesion="3"', 'adhesion="1.5" priority="1"'),
    "friction under MuJoCo's floor": ('friction="0 0 0"', 'friction="0 0 0"'),
}


@pytest.mark.parametrize("case", CASES)
def test_each_rule_of_the_mix_is_mujocos(case):
    model = _two_spheres(*CASES[case])
    assert _said(model) == _contacts_as_mujoco_makes_them(model)


def test_a_contact_is_detected_within_the_sum_of_the_gaps_and_acts_within_the_margins():
    # 2 cm apart: detected (gaps 0.01 + 0.015 > 0.02, where the larger, 0.015, would not be)
    spheres = mujoco.MjModel.from_xml_string(
        """<mujoco><worldbody><geom name="b" type="sphere" size="0.05" gap="0.015"/>
          <body pos="0 0 0.12"><freejoint/>
            <geom name="a" type="sphere" size="0.05" gap="0.01" margin="0.002"/></body>
        </worldbody></mujoco>"""
    )
    (said,) = pair_contacts(spheres)
    assert (said.margin, said.gap) == (0.002, 0.025)
    data = mujoco.MjData(spheres)
    mujoco.mj_forward(spheres, data)
    assert data.ncon == 1 and data.contact[0].exclude == 1  # in the gap: detected, not acting
    assert data.contact[0].includemargin == said.margin


def test_a_pair_replaces_the_geoms_values():
    model = _two_spheres(
        'friction="3 0.1 0.1" condim="6" priority="4"',
        'friction="2 0.1 0.1"',
        contact='<pair geom1="a" geom2="b" condim="4" friction="0.7 0.6 0.02 0.003 0.004" '
        'solref="0.03 0.8" solreffriction="0.05 1.2" solimp="0.85 0.9 0.004 0.5 2" '
        'margin="0.004" gap="0.001" adhesion="2"/>',
    )
    (said,) = pair_contacts(model)
    assert said.pair == 0
    assert said.friction == (0.7, 0.6, 0.02, 0.003, 0.004)  # the pair's own, as written
    assert _said(model) == _contacts_as_mujoco_makes_them(model)


def test_the_options_override_replaces_them_all():
    model = _two_spheres(
        'friction="3 0.1 0.1"',
        'friction="2 0.1 0.1"',
        option='<option o_margin="0.002" o_solref="0.05 0.7" o_solimp="0.8 0.85 0.01 0.5 2" '
        'o_friction="0.4 0.4 0.01 0.001 0.001"><flag override="enable"/></option>',
    )
    assert _said(model) == _contacts_as_mujoco_makes_them(model)


REACHER = Path(__file__).resolve().parents[1] / "tasks/reacher_goal/reacher.xml"


def _spheres(path: Path, rng: np.random.Generator) -> mujoco.MjModel:
    """A model as shipped with every geom a 5 cm sphere at its parent's origin (every pair
    that can collide touches) and random contact parameters on every geom, contacts on (the
    reacher ships them off)."""
    spec = mujoco.MjSpec.from_file(str(path))
    spec.option.disableflags &= ~int(mujoco.mjtDisableBit.mjDSBL_CONTACT)
    for geom in spec.geoms:
        geom.type = mujoco.mjtGeom.mjGEOM_SPHERE
        geom.size = [0.05, 0, 0]
        geom.pos = [0, 0, 0]
        geom.fromto = [np.nan] * 6  # MjSpec's "not given": the sphere's own frame
        geom.meshname = ""
        geom.friction = rng.uniform(0.05, 2, 3)
        geom.condim = int(rng.choice([1, 3, 4, 6]))
        geom.priority = int(rng.integers(0, 3))
        geom.solmix = float(rng.choice([0.0, 0.5, 1.0, 4.0]))
        geom.solref = (
            [rng.uniform(0.005, 0.05), rng.uniform(0.5, 2)]
            if rng.random() < 0.8
            else [-rng.uniform(500, 5000), -rng.uniform(5, 50)]
        )
        geom.solimp = [*sorted(rng.uniform(0.5, 0.99, 2)), rng.uniform(0.001, 0.01), 0.5, 2]
        geom.margin = rng.uniform(0, 0.004)
        geom.gap = rng.uniform(0, 0.002)
    for body in spec.bodies[1:]:
        body.pos = [0, 0, 0]
    for equality in spec.equalities:
        equality.active = False
    return spec.compile()


@pytest.mark.parametrize(
    ("path", "at_least"), [(FETCH, 100), (REACHER, 5)], ids=["fetch", "dm_control reacher"]
)
def test_every_pair_of_a_shipped_model_with_random_parameters_is_as_mujoco_makes_it(path, at_least):
    model = _spheres(path, np.random.default_rng(41))
    made = _contacts_as_mujoco_makes_them(model)
    assert sorted(made) == collision_pairs(model)  # every pair touches: each one is checked
    assert len(made) >= at_least
    assert len(set(model.geom_priority)) > 1
    assert _said(model) == made


FINGERS = """<mujoco><worldbody>
  <geom name="floor" type="plane" size="1 1 0.1" friction="{floor} 0.005 0.0001"/>
  <body name="pad"><joint type="slide"/><geom name="pad" type="box" size="0.01 0.05 0.05"
    pos="0.06 0 0.05" friction="2 0.005 0.0001"/></body>
  <body name="cube"><freejoint/>
    <geom name="cube" type="box" size="0.05 0.05 0.05" pos="0 0 0.05" friction="{cube} 0.005
      0.0001"/></body>
</worldbody></mujoco>"""


def _fingers(*, floor: float, cube: float) -> mujoco.MjModel:
    return mujoco.MjModel.from_xml_string(FINGERS.format(floor=floor, cube=cube))


def test_a_lower_friction_under_geoms_that_grip_harder_is_said_to_change_no_contact():
    before, after = _fingers(floor=1, cube=1), _fingers(floor=1, cube=0.5)
    assert describe_contact_changes(before, after) == [
        "`cube` friction 1 0.005 0.0001 -> 0.5 0.005 0.0001; its contacts with `floor` keep "
        "friction 1 0.005 0.0001; its contacts with `pad` keep friction 2 0.005 0.0001"
    ]


def test_a_contact_whose_larger_friction_was_the_edited_geoms_is_said_to_change():
    before, after = _fingers(floor=0.2, cube=1), _fingers(floor=0.2, cube=0.5)
    assert describe_contact_changes(before, after) == [
        "`cube` friction 1 0.005 0.0001 -> 0.5 0.005 0.0001; its contacts with `floor` "
        "(friction 1 0.005 0.0001 -> 0.5 0.005 0.0001) change; its contacts with `pad` keep "
        "friction 2 0.005 0.0001"
    ]


def test_the_reports_table_gives_each_pairs_values_not_each_geoms():
    model = _two_spheres(
        'friction="0.5 0.01 0.001" priority="1"', 'friction="2 0.002 0.003" condim="6"'
    )
    assert contact_lines(model)[2:] == [
        "| pairs | condim | friction (sliding, torsional, rolling) | solref | solimp "
        "| margin, gap (m) | from |",
        "| --- | --- | --- | --- | --- | --- | --- |",
        "| `b` & `a` | 3 | 0.5, 0.01, 0.001 | 0.02, 1 | 0.9, 0.95, 0.001, 0.5, 2 | 0, 0 "
        "| `a`'s (higher priority) |",
    ]
    assert _said(model) == _contacts_as_mujoco_makes_them(model)  # the row is MuJoCo's


def test_the_report_says_a_conditions_and_a_state_parameters_edit_of_a_geom_in_contact_terms():
    config = yaml.safe_load((REPO_ROOT / "config" / "config.yaml").read_text())
    config["conditions"]["fast"]["model"] = {"geom": {"cube": {"friction": [0.4, 0.003, 0.0001]}}}
    path = REPO_ROOT / config["model"]
    model = load_model(path)
    task = load_task(config["task"], repo_root=REPO_ROOT)
    grip = StateParameter("grip", "", 0.2, 0.7, ModelValue("geom", "cube", "friction"))
    task = replace(task, state_parameters=(*task.state_parameters, grip))
    lines = _contact_edit_lines(config, model, path, task)
    assert lines[-2:] == [
        "- condition `fast`: `cube` friction 0.8 0.003 0.0001 -> 0.4 0.003 0.0001; its contacts "
        "with `floor` (friction 0.8 0.005 0.0001 -> 0.6 0.005 0.0001) change; its contacts with "
        "`left_pad`, `right_pad` keep friction 0.8 0.003 0.0001",
        "- state parameter `grip` from 0.2 to 0.7: `cube` friction 0.2 0.003 0.0001 -> 0.7 0.003 "
        "0.0001; its contacts with `floor` (friction 0.6 0.005 0.0001 -> 0.7 0.005 0.0001) "
        "change; its contacts with `left_pad`, `right_pad` keep friction 0.8 0.003 0.0001",
    ]


def test_a_model_without_contacts_has_no_pairs_and_no_table():
    model = _two_spheres("", "", option='<option><flag contact="disable"/></option>')
    assert pair_contacts(model) == [] and contact_digest_values(model).shape == (0, 16)
