"""Every model compiles, holds what the protocol needs, and steps without a MuJoCo warning."""

from __future__ import annotations

import mujoco
import numpy as np
import pytest
from gantry_lift.model_spec import ModelSpec

from mjtrial import MODELS_DIR, model_path
from mjtrial.sim.physics import ModelError, load_model

MODELS = sorted(p.name for p in MODELS_DIR.iterdir() if (p / "scene.xml").is_file())


@pytest.mark.parametrize("name", MODELS)
def test_model_steps_without_warnings(name):
    model = load_model(model_path(name))
    data = mujoco.MjData(model)
    mujoco.mj_resetDataKeyframe(model, data, 0)
    for _ in range(2000):
        mujoco.mj_step(model, data)
    assert [w.number for w in data.warning] == [0] * mujoco.mjtWarning.mjNWARNING.value
    assert np.isfinite(data.qpos).all()


def test_gantry_layout_matches_design(gantry_model):
    m = gantry_model
    joints = [m.joint(i).name for i in range(m.njnt)]
    assert joints == ["gantry_x", "gantry_y", "gantry_z", "left_finger", "right_finger", "cube"]
    assert [int(m.jnt_qposadr[i]) for i in range(m.njnt)] == [0, 1, 2, 3, 4, 5]
    assert ModelSpec.of(m).cube_qpos == 5 and m.nq == 12
    assert [m.actuator(i).name for i in range(m.nu)] == ["x", "y", "z", "gripper"]
    # Controlled variables are explicit in the file.
    assert m.opt.timestep == 0.002
    assert m.opt.integrator == mujoco.mjtIntegrator.mjINT_IMPLICITFAST
    assert m.opt.cone == mujoco.mjtCone.mjCONE_ELLIPTIC
    assert m.opt.impratio == 10
    np.testing.assert_array_equal(m.key_ctrl[0], [0.12, 0, 0, 0.04])


def test_home_pose_rests_cube_on_floor_and_z_target_reaches_it(gantry_model):
    m = gantry_model
    d = mujoco.MjData(m)
    mujoco.mj_resetDataKeyframe(m, d, 0)
    for _ in range(250):
        mujoco.mj_step(m, d)
    assert d.qpos[7] == pytest.approx(0.02, abs=5e-4)  # cube resting on the floor
    pad = m.geom("left_pad").id
    d.ctrl[2] = -0.33
    for _ in range(1000):
        mujoco.mj_step(m, d)
    # z target -0.33 brings the pads around the cube's centre height.
    assert d.geom_xpos[pad][2] == pytest.approx(0.02, abs=3e-3)


def test_model_path_names_unknown_model():
    with pytest.raises(FileNotFoundError, match="no_such_model"):
        model_path("no_such_model")


@pytest.mark.parametrize(
    ("renames", "missing"),
    [
        ({'name="left_pad_cube"': 'name="renamed_sensor"'}, "sensor named 'left_pad_cube'"),
        (
            {'name="gantry_z"': 'name="lift"', 'joint="gantry_z"': 'joint="lift"'},
            "joint named 'gantry_z'",
        ),
        (
            {'name="right_pad"': 'name="other_pad"', '"right_pad"': '"other_pad"'},
            "geom named 'right_pad'",
        ),
    ],
)
def test_model_spec_names_the_missing_element(tmp_path, renames, missing):
    """A model without an element the protocol reads fails at load, naming file and element."""
    src = model_path("gantry_gripper").parent
    for f in src.iterdir():
        (tmp_path / f.name).write_bytes(f.read_bytes())
    model = tmp_path / "gantry_gripper.xml"
    text = model.read_text()
    for old, new in renames.items():
        assert old in text
        text = text.replace(old, new)
    model.write_text(text)
    compiled = load_model(tmp_path / "scene.xml")  # it compiles: the gantry's spec refuses it
    with pytest.raises(ModelError, match=f"scene.xml: expected a {missing}"):
        ModelSpec.of(compiled, source=str(tmp_path / "scene.xml"))


def test_model_spec_indices_match_the_compiled_model(gantry_model):
    m, spec = gantry_model, ModelSpec.of(gantry_model)
    assert m.body(spec.cube_body).name == "cube"
    assert [m.geom(g).name for g in spec.pad_geoms] == ["left_pad", "right_pad"]
    assert [m.body(b).name for b in spec.pad_bodies] == ["left_finger", "right_finger"]
    assert m.body(spec.carriage_body).name == "carriage"
    assert [int(m.sensor_adr[m.sensor(s).id]) for s in ("left_pad_cube", "right_pad_cube")] == list(
        spec.pad_sensors
    )
