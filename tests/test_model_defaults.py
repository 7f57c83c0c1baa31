"""A condition or a variant may edit a default class's values, as the same edit of the class in
the file would: MuJoCo applies a class when it parses, so an edit of `MjSpec.find_default`
after parsing alone reaches no element. Checked against the file edited by text: dm_control's
reacher as shipped (its `main` class sets the joints' damping and the motors' gear), and a model
of nested classes."""

from __future__ import annotations

import re
import shutil
from pathlib import Path

import mujoco
import numpy as np
import pytest
import yaml
from conftest import REPO_ROOT

from mjtrial.config import ConfigError, check_config
from mjtrial.design.conditions import condition_record
from mjtrial.report.labels import setting
from mjtrial.sim.physics import compiled_sha256
from mjtrial.stages.manifest import condition_edits
from mjtrial.studies.variants import variant_model
from mjtrial.task import load_task

REACHER = REPO_ROOT / "tasks" / "reacher_goal"
DEFAULT_EDITS = {
    "default": {
        "main": {
            "joint": {"damping": [0.03, 0, 0]},
            "actuator": {"gear": [0.1, 0, 0, 0, 0, 0]},
        }
    }
}


def _text_edited(folder: Path, tmp_path: Path, edits: dict[str, str]) -> Path:
    """A copy of `folder` whose model has each `old` text replaced by `new`, once."""
    copy = tmp_path / folder.name
    shutil.copytree(folder, copy)
    path = copy / "reacher.xml"
    text = path.read_text()
    for old, new in edits.items():
        text, count = re.subn(re.escape(old), new, text)
        assert count == 1, old
    path.write_text(text)
    return path


def test_the_reachers_main_class_edited_is_the_file_edited_by_text(tmp_path):
    edited, digest = variant_model(
        REACHER / "reacher.xml", {}, then=[(DEFAULT_EDITS, "conditions.x.model")]
    )
    by_hand = mujoco.MjModel.from_xml_path(
        str(
            _text_edited(
                REACHER,
                tmp_path,
                {
                    '<joint type="hinge" axis="0 0 1" damping="0.01"/>': (
                        '<joint type="hinge" axis="0 0 1" damping="0.03"/>'
                    ),
                    '<motor gear=".05"': '<motor gear=".1"',
                },
            )
        )
    )
    np.testing.assert_array_equal(edited.dof_damping, [0.03, 0.03])
    np.testing.assert_array_equal(edited.actuator_gear[:, 0], [0.1, 0.1])
    assert digest == compiled_sha256(by_hand)
    nominal = mujoco.MjModel.from_xml_path(str(REACHER / "reacher.xml"))
    assert compiled_sha256(nominal) != digest


def test_a_default_edit_is_the_same_model_as_editing_each_joint(tmp_path):
    # config/reacher_damping.yaml's condition, written per joint, against the class
    joints = {"joint": {j: {"damping": [0.03, 0, 0]} for j in ("shoulder", "wrist")}}
    per_joint = variant_model(REACHER / "reacher.xml", joints)[1]
    by_class = {"default": {"main": {"joint": {"damping": [0.03, 0, 0]}}}}
    assert variant_model(REACHER / "reacher.xml", by_class)[1] == per_joint


NESTED = """<mujoco>
  <default>
    <joint damping="1"/>
    <default class="inherits">
      <joint armature="0.2"/>
      <default class="below">
        <geom size="0.02"/>
      </default>
    </default>
    <default class="own">
      <joint damping="3"/>
    </default>
  </default>
  <worldbody>
    <body name="a">
      <joint name="main_joint" axis="0 1 0"/>
      <geom size="0.1"/>
      <body name="b" pos="0 0 0.3">
        <joint name="inherits_joint" class="inherits" axis="0 1 0"/>
        <geom size="0.1"/>
        <body name="c" pos="0 0 0.3">
          <joint name="below_joint" class="below" axis="0 1 0"/>
          <joint name="sets_its_own" class="below" axis="1 0 0" damping="5"/>
          <joint name="own_joint" class="own" axis="0 0 1"/>
          <geom size="0.1"/>
        </body>
      </body>
    </body>
  </worldbody>
</mujoco>
"""


def test_nested_classes_inherit_the_edit_where_the_file_would(tmp_path):
    path = tmp_path / "nested.xml"
    path.write_text(NESTED)
    edits = {"default": {"main": {"joint": {"damping": [7, 0, 0]}}}}
    edited = variant_model(path, edits)[0]
    by_hand = mujoco.MjModel.from_xml_string(
        NESTED.replace('<joint damping="1"/>', '<joint damping="7"/>')
    )
    # main, inherits and below take 7; the joint setting 5 and the class setting 3 keep theirs
    np.testing.assert_array_equal(edited.dof_damping, [7, 7, 7, 5, 3])
    np.testing.assert_array_equal(edited.dof_damping, by_hand.dof_damping)
    assert compiled_sha256(edited) == compiled_sha256(by_hand)


def _reacher_config() -> dict:
    config = yaml.safe_load((REPO_ROOT / "config" / "reacher_damping.yaml").read_text())
    config["states"]["n"] = 16
    return config


@pytest.mark.parametrize(
    ("edits", "message"),
    [
        (
            {"default": {"arm": {"joint": {"damping": [0.03, 0, 0]}}}},
            "conditions.damping_x3.model.default.arm: the model has no default class of that "
            "name; expected one of main",
        ),
        (
            {"default": {"main": {"motor": {"gear": [0.1, 0, 0, 0, 0, 0]}}}},
            "conditions.damping_x3.model.default.main.motor: expected one of joint, geom",
        ),
        (
            {"default": {"main": {"joint": {"dampin": [0.03, 0, 0]}}}},
            "conditions.damping_x3.model.default.main.joint.dampin: unknown or not overridable",
        ),
        (
            {"default": {"main": {"joint": {"damping": 0.03}}}},
            "conditions.damping_x3.model.default.main.joint.damping: expected 3 numbers",
        ),
    ],
)
def test_a_bad_default_edit_is_one_line_naming_the_file_and_key(edits, message):
    config = _reacher_config()
    config["conditions"]["damping_x3"]["model"] = edits
    with pytest.raises(ConfigError) as caught:
        check_config(config, source="config/reacher_damping.yaml", repo_root=REPO_ROOT)
    assert str(caught.value).startswith(f"config/reacher_damping.yaml: {message}"), str(
        caught.value
    )
    assert "\n" not in str(caught.value)


def test_the_manifest_and_report_say_what_a_default_edit_changed():
    config = _reacher_config()
    config["conditions"]["damping_x3"]["model"] = DEFAULT_EDITS
    record = condition_record(load_task(config["task"]), config["conditions"]["damping_x3"])
    assert record["model"] == DEFAULT_EDITS  # the summary's record of the condition
    assert setting(record, load_task(config["task"])).endswith(
        "default main joint damping 0.03 0 0; default main actuator gear 0.1 0 0 0 0 0"
    )  # the report's conditions table
    edits = condition_edits(config, REPO_ROOT / config["model"])  # the manifest's
    assert edits["damping_x3"]["edits"] == DEFAULT_EDITS
    expected = variant_model(REACHER / "reacher.xml", DEFAULT_EDITS)[1]
    assert edits["damping_x3"]["compiled_sha256"] == expected
