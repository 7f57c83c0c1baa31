"""Addresses of unnamed model elements (`mjtrial.task.address`): resolved and described against
the compiled model's own fields, and used by a condition's model edits, which must give the
model a hand edit of the XML gives."""

from __future__ import annotations

import shutil
from pathlib import Path

import mujoco
import numpy as np
import pytest
from policy_graphs import tanh_mlp, write

from mjtrial.policy_files.file import PolicyFileError, load_policy_file
from mjtrial.report.actuators import actuator_lines
from mjtrial.sim.physics import compiled_sha256, load_model, load_spec
from mjtrial.studies.variants import SPEC_ELEMENTS, apply_overrides, variant_model
from mjtrial.task import ModelValue, TaskError, address, load_task

REPO = Path(__file__).resolve().parents[1]
FETCH_DIR = REPO / "tasks" / "fetch_pick" / "assets"
FETCH = FETCH_DIR / "fetch" / "pick_and_place.xml"
WELD = '<weld body1="robot0:mocap" body2="robot0:gripper_link" solimp="0.9 0.95 0.001" '

# Unnamed elements of every kind an override names, each with a value of its own, in a tree
# whose depth-first and breadth-first orders differ: the spec's lists must be in compiled order.
UNNAMED = """
<mujoco>
  <worldbody>
    <body pos="0 0 1">
      <joint type="hinge" damping="0.1"/>
      <geom size="0.11"/>
      <site size="0.21"/>
      <body pos="0 0 2">
        <joint type="slide" damping="0.2"/>
        <geom size="0.12"/>
        <site size="0.22"/>
      </body>
    </body>
    <body name="b" pos="0 0 3">
      <joint name="j" type="hinge" damping="0.3"/>
      <geom size="0.13"/>
      <site size="0.23"/>
    </body>
  </worldbody>
  <tendon>
    <fixed stiffness="4"><joint joint="j" coef="1"/></fixed>
    <fixed stiffness="5"><joint joint="j" coef="2"/></fixed>
  </tendon>
  <equality><joint joint1="j" polycoef="0 5 0 0 0"/><connect body1="b" anchor="0 0 6"/></equality>
  <actuator><motor joint="j" gear="7"/><position joint="j" kp="8"/></actuator>
  <sensor>
    <jointpos joint="j" noise="0.9"/><framepos objtype="body" objname="b" noise="0.8"/>
  </sensor>
</mujoco>
"""
# the spec's value and the compiled model's of one attribute per kind: pairs must agree by index
SIGNATURE = {
    "body": ("pos", lambda m: m.body_pos),
    "joint": ("damping", lambda m: m.dof_damping[m.jnt_dofadr]),
    "geom": ("size", lambda m: m.geom_size),
    "site": ("size", lambda m: m.site_size),
    "tendon": ("stiffness", lambda m: m.tendon_stiffness),
    "actuator": ("gear", lambda m: m.actuator_gear),
    "equality": ("data", lambda m: m.eq_data),
    "sensor": ("noise", lambda m: m.sensor_noise),
}


@pytest.fixture(scope="module")
def fetch() -> mujoco.MjModel:
    return load_model(FETCH)


def test_spec_lists_are_in_the_compiled_order():
    spec = mujoco.MjSpec.from_string(UNNAMED)
    model = spec.compile()
    assert set(SIGNATURE) == set(SPEC_ELEMENTS)
    for kind, (attribute, compiled) in SIGNATURE.items():
        elements = getattr(spec, SPEC_ELEMENTS[kind])
        assert len(elements) == address.count(model, kind) > 1, kind
        for i, element in enumerate(elements):
            ours = np.atleast_1d(getattr(element, attribute)).ravel()
            theirs = np.atleast_1d(compiled(model)[i]).ravel()
            n = min(ours.size, theirs.size, 3)
            np.testing.assert_array_equal(ours[:n], theirs[:n], err_msg=f"{kind} {i}")


def test_resolve_by_name_index_and_attachment(fetch):
    weld = 0
    mocap = mujoco.mj_name2id(fetch, mujoco.mjtObj.mjOBJ_BODY, "robot0:mocap")
    gripper = mujoco.mj_name2id(fetch, mujoco.mjtObj.mjOBJ_BODY, "robot0:gripper_link")
    assert (fetch.eq_obj1id[weld], fetch.eq_obj2id[weld]) == (mocap, gripper)
    assert address.resolve(fetch, "equality", "#0") == weld
    assert address.resolve(fetch, "eq", "on:robot0:mocap") == weld
    assert address.resolve(fetch, mujoco.mjtObj.mjOBJ_EQUALITY, "on:robot0:gripper_link") == weld
    for i in range(fetch.nu):
        joint = mujoco.mj_id2name(fetch, mujoco.mjtObj.mjOBJ_JOINT, fetch.actuator_trnid[i, 0])
        assert address.resolve(fetch, "actuator", f"on:{joint}") == i
        assert address.resolve(fetch, "actuator", fetch.actuator(i).name) == i
    site = mujoco.mj_name2id(fetch, mujoco.mjtObj.mjOBJ_SITE, "target0")
    assert address.resolve(fetch, "site", "target0") == site


@pytest.mark.parametrize(
    ("kind", "ref", "expected"),
    [
        ("equality", "#1", r"^expected '#<index>' with an index 0 to 0 among the model's 1 "),
        ("equality", "#x", "got '#x'"),
        ("equality", "#²", r"^expected '#<index>' with an index 0 to 0 among the model's 1 .*'#²'"),
        ("geom", "#٣", r"^expected '#<index>' with an index 0 to .*got '#٣'$"),  # Arabic-Indic 3
        ("equality", "on:robot0:base_link", "attached to an element named 'robot0:base_link'"),
        ("actuator", "gripper", "^expected an actuator named 'gripper' in the model$"),
        ("geom", "on:robot0:mocap", r"'on:robot0:mocap' is ambiguous: 4 geoms .*#1: geom 1 of"),
        ("widget", "x", "expected an element kind of"),
    ],
)
def test_a_bad_address_is_one_line(fetch, kind, ref, expected):
    with pytest.raises(address.AddressError, match=expected) as err:
        address.resolve(fetch, kind, ref)
    assert "\n" not in str(err.value)


def test_describe_names_what_an_unnamed_element_is_attached_to(fetch):
    obj = mujoco.mjtObj
    ends = [mujoco.mj_id2name(fetch, obj.mjOBJ_BODY, fetch.eq_obj1id[0])]
    ends.append(mujoco.mj_id2name(fetch, obj.mjOBJ_BODY, fetch.eq_obj2id[0]))
    assert fetch.eq_type[0] == mujoco.mjtEq.mjEQ_WELD
    assert address.describe(fetch, "equality", 0) == f"weld 0 ({ends[0]} to {ends[1]})"
    unnamed = [g for g in range(fetch.ngeom) if not fetch.geom(g).name]
    assert unnamed
    for g in unnamed:
        body = fetch.body(fetch.geom_bodyid[g]).name
        assert address.describe(fetch, "geom", g) == f"geom {g} of body {body}"
    assert address.describe(fetch, "actuator", 1) == fetch.actuator(1).name  # named: its name
    assert address.describe(fetch, "body", 0) == "world"
    # an unnamed actuator and sensor: what they act on
    model = mujoco.MjModel.from_xml_string(UNNAMED)
    joint = mujoco.mj_name2id(model, obj.mjOBJ_JOINT, "j")
    assert model.actuator_trnid[0, 0] == joint
    assert address.describe(model, "actuator", 0) == "actuator 0 on joint j"
    assert address.describe(model, "sensor", 1) == "sensor 1 (framepos) on body b"
    assert address.describe(model, "equality", 0) == "joint 0 (j)"
    assert address.describe(model, "body", 2) == "body 2 (child of body 1 (child of world))"
    with pytest.raises(address.AddressError, match="ambiguous: 2 actuators"):
        address.resolve(model, "actuator", "on:j")


def _hand_edited(tmp_path: Path, solref: str) -> mujoco.MjModel:
    """The Fetch model with the weld's solref edited in the XML text, in a copy of its folder."""
    root = tmp_path / "assets"
    shutil.copytree(FETCH_DIR, root)
    shared = root / "fetch" / "shared.xml"
    text = shared.read_text()
    assert text.count(WELD + 'solref="0.02 1"') == 1
    shared.write_text(text.replace(WELD + 'solref="0.02 1"', WELD + f'solref="{solref}"'))
    return load_model(root / "fetch" / "pick_and_place.xml")


@pytest.mark.parametrize("ref", ["#0", "on:robot0:mocap", "on:robot0:gripper_link"])
def test_a_condition_edits_the_unnamed_weld_as_the_xml_would(tmp_path, ref):
    by_hand = _hand_edited(tmp_path, "0.05 0.7")
    nominal, nominal_hash = variant_model(FETCH, {})
    edits = {"equality": {ref: {"solref": [0.05, 0.7]}}}
    model, sha = variant_model(FETCH, {}, then=[(edits, "conditions.soft.model")])
    np.testing.assert_array_equal(model.eq_solref[0], [0.05, 0.7])
    np.testing.assert_array_equal(nominal.eq_solref[0], [0.02, 1.0])
    assert sha == compiled_sha256(by_hand) != nominal_hash


@pytest.mark.parametrize(
    ("ref", "expected"),
    [
        ("#3", r"^conditions\.soft\.model\.equality\.#3: expected '#<index>' with an index 0"),
        ("on:table0", r"^conditions\.soft\.model\.equality\.on:table0: expected an equality"),
        ("weld", r"^conditions\.soft\.model\.equality\.weld: the model has no equality of that"),
    ],
)
def test_a_bad_address_in_a_condition_is_one_line(ref, expected):
    with pytest.raises(ValueError, match=expected) as err:
        apply_overrides(
            load_spec(FETCH),
            {"equality": {ref: {"solref": [0.05, 1]}}},
            key_prefix="conditions.soft.model",
        )
    assert "\n" not in str(err.value)


def test_a_state_parameter_sets_an_unnamed_element(fetch):
    scratch = mujoco.MjData(fetch)
    for ref in ("#0", "on:robot0:mocap"):
        model = mujoco.MjModel.from_xml_path(str(FETCH))
        ModelValue("eq", ref, "solref", 0).bind(fetch)(model, scratch, 0.04)
        assert model.eq_solref[0, 0] == 0.04
    with pytest.raises(TaskError, match="^expected an equality attached to an element named 'x'"):
        ModelValue("eq", "on:x", "solref", 0).bind(fetch)


def test_the_report_labels_an_unnamed_actuator_by_its_joint():
    lines = actuator_lines(mujoco.MjModel.from_xml_string(UNNAMED))
    assert any(line.startswith("  - actuator 0 on joint `j`: ") for line in lines), lines
    assert not any("`actuator 0`" in line for line in lines)


@pytest.mark.parametrize("ref", ["cart_motor", "#0", "on:cart_slide"])
def test_a_policy_contract_names_an_actuator_by_address(tmp_path, ref):
    task = load_task(REPO / "tasks" / "cartpole_latency" / "task.py")
    policy = load_policy_file(write(tmp_path, "net", tanh_mlp([2, 8, 1]), actuators=[ref]), task)
    model = load_model(task.model)
    params = task.parameters({})
    np.testing.assert_array_equal(policy.policy(model, params).columns, [0])


def test_a_policy_contracts_bad_actuator_address_is_one_line(tmp_path):
    task = load_task(REPO / "tasks" / "cartpole_latency" / "task.py")
    path = write(tmp_path, "net", tanh_mlp([2, 8, 1]), actuators=["on:pole_hinge"])
    policy = load_policy_file(path, task)
    with pytest.raises(
        PolicyFileError,
        match=r"net\.yaml: actuators: 'on:pole_hinge': expected an "
        r"actuator attached to an element named 'pole_hinge', found none \(its "
        r"actuators: \['cart_motor'\]\)$",
    ) as err:
        policy.policy(load_model(task.model), task.parameters({}))
    assert "\n" not in str(err.value)
