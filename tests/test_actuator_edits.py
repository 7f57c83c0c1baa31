"""A condition or a variant edits an actuator by its MJCF attributes (`kp`, `kv`, a muscle's
`force`, `scale`, `timeconst`) and any numeric attribute by a factor (`{factor: 0.7}` or
`"x 0.7"`). The reference is MuJoCo's own compiler: the same model written with the edited
value in its XML compiles to the same parameter arrays, bit for bit (issue 41, item 8)."""

from __future__ import annotations

import mujoco
import numpy as np
import pytest
import yaml
from conftest import REPO_ROOT

from mjtrial.config import check_config
from mjtrial.studies.variants import apply_overrides, describe_edits, variant_model

ARM = """<mujoco><worldbody><body><joint name="hinge" type="hinge"/>
  <geom name="link" type="capsule" size="0.02" fromto="0 0 0 0.3 0 0" friction="{friction}"/>
  <site name="a" pos="0 0 0.01"/><site name="b" pos="0.3 0 0.01"/>
</body></worldbody>
<tendon><spatial name="t"><site site="a"/><site site="b"/></spatial></tendon>
<actuator>{actuator}</actuator></mujoco>"""


def _compiled(actuator: str, friction: str = "1 0.005 0.0001", edits: dict | None = None):
    spec = mujoco.MjSpec.from_string(ARM.format(actuator=actuator, friction=friction))
    if edits:
        apply_overrides(spec, edits, key_prefix="conditions.weak.model")
    return spec.compile()


def _same_actuators(a: mujoco.MjModel, b: mujoco.MjModel) -> None:
    for field in ("gainprm", "biasprm", "dynprm", "gear", "forcerange", "ctrlrange"):
        np.testing.assert_array_equal(
            getattr(a, f"actuator_{field}"), getattr(b, f"actuator_{field}")
        )


CASES = {
    "a position servo's kp": (
        '<position name="m" joint="hinge" kp="{}" kv="3"/>',
        "kp",
        100.0,
        70.0,
    ),
    "a position servo's kv": ('<position name="m" joint="hinge" kp="50" kv="{}"/>', "kv", 4.0, 1.5),
    "a velocity servo's kv": ('<velocity name="m" joint="hinge" kv="{}"/>', "kv", 8.0, 2.0),
    "a damper's kv": ('<damper name="m" joint="hinge" kv="{}" ctrlrange="0 1"/>', "kv", 5.0, 0.5),
    "a muscle's force": (
        '<muscle name="m" tendon="t" force="{}" lengthrange="0.2 0.4"/>',
        "force",
        120.0,
        84.0,
    ),
    "a muscle's scale": (
        '<muscle name="m" tendon="t" scale="{}" lengthrange="0.2 0.4"/>',
        "scale",
        300.0,
        210.0,
    ),
    "a muscle's vmax": (
        '<muscle name="m" tendon="t" force="50" vmax="{}" lengthrange="0.2 0.4"/>',
        "vmax",
        1.5,
        2.0,
    ),
    "a filtered servo's timeconst": (
        '<position name="m" joint="hinge" kp="40" timeconst="{}"/>',
        "timeconst",
        0.05,
        0.02,
    ),
}


@pytest.mark.parametrize("case", CASES)
def test_an_mjcf_attribute_edit_is_what_mujoco_compiles_from_that_value(case):
    actuator, attribute, loaded, edited = CASES[case]
    reference = _compiled(actuator.format(edited))
    given = _compiled(actuator.format(loaded), edits={"actuator": {"m": {attribute: edited}}})
    _same_actuators(given, reference)
    with pytest.raises(AssertionError):  # the edit is one: the model as loaded differs
        _same_actuators(_compiled(actuator.format(loaded)), reference)


@pytest.mark.parametrize("factor", [{"factor": 0.7}, "x 0.7"], ids=["mapping", "text"])
def test_a_factor_scales_the_value_as_loaded(factor):
    actuator = '<muscle name="m" tendon="t" force="{}" lengthrange="0.2 0.4"/>'
    reference = _compiled(actuator.format(repr(120.0 * 0.7)))
    given = _compiled(actuator.format(120.0), edits={"actuator": {"m": {"force": factor}}})
    _same_actuators(given, reference)


def test_a_muscles_two_time_constants_and_a_gear_and_a_geoms_friction_by_factor():
    muscle = (
        '<muscle name="m" tendon="t" force="60" timeconst="{}" gear="{}" lengthrange="0.2 0.4"/>'
    )
    reference = _compiled(muscle.format("0.02 0.08", repr(1.5 * 2)), friction=f"{0.5} 0.0025 5e-05")
    given = _compiled(
        muscle.format("0.01 0.04", 1.5),
        edits={
            "actuator": {"m": {"timeconst": {"factor": 2}, "gear": "x 2"}},
            "geom": {"link": {"friction": {"factor": 0.5}}},
        },
    )
    _same_actuators(given, reference)
    np.testing.assert_array_equal(given.geom_friction, reference.geom_friction)


@pytest.mark.parametrize(
    ("actuator", "edit", "message"),
    [
        (
            '<motor name="m" joint="hinge"/>',
            {"kp": 10},
            "conditions.weak.model.actuator.m.kp: this is a general actuator, which has no 'kp'",
        ),
        (
            '<muscle name="m" tendon="t" lengthrange="0.2 0.4"/>',
            {"force": {"factor": 0.7}},
            "conditions.weak.model.actuator.m.force: this muscle's force is MuJoCo's own",
        ),
        (
            '<muscle name="m" tendon="t" force="10" lengthrange="0.2 0.4"/>',
            {"force": "x -1"},
            "conditions.weak.model.actuator.m.force: expected a positive factor, got -1.0",
        ),
        (
            '<motor name="m" joint="hinge"/>',
            {"gear": {"times": 2}},
            "conditions.weak.model.actuator.m.gear: expected a value, or {factor: <number>}",
        ),
    ],
    ids=["kp on a motor", "factor of an automatic force", "negative factor", "bad mapping"],
)
def test_a_wrong_actuator_edit_is_one_line_naming_the_key(actuator, edit, message):
    with pytest.raises(ValueError) as err:
        _compiled(actuator, edits={"actuator": {"m": edit}})
    assert str(err.value).startswith(message)
    assert "\n" not in str(err.value)


def test_the_report_says_a_factor_as_a_factor():
    edits = {"actuator": {"biceps": {"force": {"factor": 0.7}, "timeconst": "x 2"}}}
    assert describe_edits(edits) == "actuator biceps force x 0.7; actuator biceps timeconst x 2"


def test_a_condition_weakens_the_gantrys_gripper_by_a_factor_through_the_config_check():
    config = yaml.safe_load((REPO_ROOT / "config" / "config.yaml").read_text())
    config["conditions"]["fast"]["model"] = {"actuator": {"gripper": {"kp": "x 0.7"}}}
    config.pop("variants")
    check_config(config, source="config/config.yaml", repo_root=REPO_ROOT)
    model, _ = variant_model(
        REPO_ROOT / config["model"], {}, then=[(config["conditions"]["fast"]["model"], "c")]
    )
    gripper = model.actuator("gripper")
    assert (gripper.gainprm[0], gripper.biasprm[1]) == (4000 * 0.7, -4000 * 0.7)  # kp="4000"


def test_a_factor_of_an_option_and_of_a_default_class():
    xml = """<mujoco><option timestep="{}"/><default><joint damping="{}"/></default>
      <worldbody><body><joint name="j"/><geom size="0.1"/></body></worldbody></mujoco>"""
    reference = mujoco.MjModel.from_xml_string(xml.format(0.002 * 0.5, 0.4 * 3))
    spec = mujoco.MjSpec.from_string(xml.format(0.002, 0.4))
    edits = {"option": {"timestep": "x 0.5"}, "default": {"main": {"joint": {"damping": "x 3"}}}}
    apply_overrides(spec, edits)
    given = spec.compile()
    assert given.opt.timestep == reference.opt.timestep
    np.testing.assert_array_equal(given.dof_damping, reference.dof_damping)
