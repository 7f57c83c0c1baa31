"""Variants edit exactly the attribute they name, checked on the compiled model."""

from __future__ import annotations

import hashlib
import tempfile
from pathlib import Path

import mujoco
import numpy as np
import pytest

from mjtrial import model_path
from mjtrial.studies.variants import check_overrides, nominal_model_hash, variant_model

MODEL = model_path("gantry_gripper")
FRICTION = [0.6, 0.003, 0.0001]


def _fields(model: mujoco.MjModel) -> dict[str, np.ndarray]:
    """Every array of the model and of its options, by name."""
    out = {}
    for owner, prefix in ((model, ""), (model.opt, "opt.")):
        for name in dir(owner):
            value = getattr(owner, name) if not name.startswith("_") else None
            if isinstance(value, np.ndarray | float | int) and not isinstance(value, bool):
                out[prefix + name] = np.array(value, copy=True)
    return out


@pytest.fixture(scope="module")
def nominal() -> dict[str, np.ndarray]:
    return _fields(mujoco.MjModel.from_xml_path(str(MODEL)))


def _mjb_sha256(model: mujoco.MjModel, *, asset_paths: tuple[str, ...] = ()) -> str:
    """The compiled model's bytes as MuJoCo writes them to an MJB file, with the asset files'
    paths it keeps blanked (a model hash says what the files hold, not where), hashed."""
    with tempfile.TemporaryDirectory() as folder:
        path = Path(folder) / "model.mjb"
        mujoco.mj_saveModel(model, str(path), None)
        mjb = path.read_bytes()
    for asset in asset_paths:
        assert mjb.count(asset.encode()) == 1
        mjb = mjb.replace(asset.encode(), b"\0" * len(asset))
    return hashlib.sha256(mjb).hexdigest()


def _element_id(kind: mujoco.mjtObj, name: str) -> int:
    return mujoco.mj_name2id(mujoco.MjModel.from_xml_path(str(MODEL)), kind, name)


CASES = [
    ({"option": {"timestep": 0.001}}, "opt.timestep", None, 0.001),
    (
        {"option": {"integrator": "RK4"}},
        "opt.integrator",
        None,
        int(mujoco.mjtIntegrator.mjINT_RK4),
    ),
    (
        {"option": {"cone": "pyramidal"}},
        "opt.cone",
        None,
        int(mujoco.mjtCone.mjCONE_PYRAMIDAL),
    ),
    ({"option": {"impratio": 1}}, "opt.impratio", None, 1.0),
    (
        {"geom": {"left_pad": {"friction": FRICTION}}},
        "geom_friction",
        ("geom", "left_pad"),
        FRICTION,
    ),
    (
        {"actuator": {"gripper": {"forcerange": [-15, 15]}}},
        "actuator_forcerange",
        ("actuator", "gripper"),
        [-15.0, 15.0],
    ),
    (
        {"body": {"carriage": {"gravcomp": 0.5}}},
        "body_gravcomp",
        ("body", "carriage"),
        0.5,
    ),
]


@pytest.mark.parametrize(("overrides", "field", "element", "expected"), CASES)
def test_variant_edits_exactly_the_named_attribute(nominal, overrides, field, element, expected):
    model, _ = variant_model(MODEL, overrides)
    changed = _fields(model)
    assert changed.keys() == nominal.keys()
    different = [k for k in nominal if not np.array_equal(nominal[k], changed[k], equal_nan=True)]
    assert different == [field]
    if element is None:
        assert changed[field] == pytest.approx(expected)
        return
    kind = {"geom": mujoco.mjtObj.mjOBJ_GEOM, "actuator": mujoco.mjtObj.mjOBJ_ACTUATOR}.get(
        element[0], mujoco.mjtObj.mjOBJ_BODY
    )
    row = _element_id(kind, element[1])
    rows = np.flatnonzero(
        (nominal[field] != changed[field]).reshape(len(nominal[field]), -1).any(axis=1)
    )
    assert rows.tolist() == [row]
    np.testing.assert_array_equal(changed[field][row], expected)


def test_no_overrides_is_the_committed_model_and_its_hash(nominal):
    model, digest = variant_model(MODEL, {})
    assert all(np.array_equal(v, _fields(model)[k], equal_nan=True) for k, v in nominal.items())
    assert (
        digest == _mjb_sha256(mujoco.MjModel.from_xml_path(str(MODEL))) == nominal_model_hash(MODEL)
    )
    assert variant_model(MODEL, {"option": {"timestep": 0.001}})[1] != digest


@pytest.mark.parametrize(
    ("overrides", "message"),
    [
        (
            {"geom": {"left_pad": {"friction": [0.6, 0.003]}}},
            "v.x.geom.left_pad.friction: expected 3 numbers, got 2",
        ),
        ({"option": {"timestepp": 0.001}}, "v.x.option.timestepp: unknown option; expected one"),
        (
            {"option": {"integrator": "rk4"}},
            "v.x.option.integrator: expected one of Euler, RK4, implicit, implicitfast, got 'rk4'",
        ),
        ({"option": {"cone": "round"}}, "v.x.option.cone: expected one of pyramidal, elliptic"),
        ({"option": {"timestep": 0}}, "v.x.option.timestep: expected a positive number, got 0"),
        ({"option": {"timestep": -1e-3}}, "v.x.option.timestep: expected a positive number"),
        ({"geom": {"thumb": {"friction": FRICTION}}}, "v.x.geom.thumb: the model has no geom"),
        ({"actuator": {"gripper": {"forcerange": "15"}}}, "v.x.actuator.gripper.forcerange:"),
        ({"actuator": {"gripper": {"area": 1}}}, "v.x.actuator.gripper.area: unknown or not"),
        ({"body": {"cube": {"mass": 1.0}}}, "v.x.body.cube.mass: unknown or not overridable"),
        ({"camera": {"top": {"fovy": 30}}}, "v.x.camera: unknown override kind"),
        ({"joint": {"gantry_z": {"damping": 1}}}, "v.x.joint.gantry_z.damping: expected 3 numbers"),
        ({"geom": {"left_pad": {"condim": 3.5}}}, "v.x.geom.left_pad.condim: expected an integer"),
    ],
)
def test_bad_overrides_name_the_key(overrides, message):
    with pytest.raises(ValueError) as err:
        check_overrides(overrides, model_file=MODEL, key_prefix="v.x")
    assert str(err.value).startswith(message)
    assert "\n" not in str(err.value)


def with_a_mesh(folder):
    """A copy of the gantry's model folder whose scene adds a rock, a mesh in assets/."""
    import shutil

    shutil.copytree(model_path("gantry_gripper").parent, folder)
    (folder / "assets").mkdir()
    corners = [(x, y, z) for x in (-0.1, 0.1) for y in (-0.1, 0.1) for z in (0.0, 0.1)]
    (folder / "assets" / "rock.obj").write_text("".join(f"v {x} {y} {z}\n" for x, y, z in corners))
    scene = folder / "scene.xml"
    scene.write_text(
        scene.read_text().replace(
            "<worldbody>",
            '<asset><mesh name="rock" file="assets/rock.obj"/></asset>\n  <worldbody>\n'
            '    <geom name="rock" type="mesh" mesh="rock" pos="0.6 0.6 0"/>',
        )
    )
    return scene


def test_a_variant_of_a_model_with_a_mesh_compiles_in_the_model_folder(tmp_path):
    """Survey case 11: the edited model is compiled where its meshes are."""
    scene = with_a_mesh(tmp_path / "gantry")
    committed = mujoco.MjModel.from_xml_path(str(scene))
    model, sha256 = variant_model(scene, {"geom": {"rock": {"friction": [0.5, 0.01, 0.001]}}})
    rock = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_GEOM, "rock")
    assert model.geom_friction[rock, 0] == 0.5
    np.testing.assert_array_equal(model.mesh_vert, committed.mesh_vert)
    spec = mujoco.MjSpec.from_file(str(scene))
    spec.geom("rock").friction = [0.5, 0.01, 0.001]
    assert sha256 == _mjb_sha256(spec.compile(), asset_paths=("assets/rock.obj",))
