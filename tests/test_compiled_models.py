"""Compiled models kept between the workflow's processes (`physics.load_model(compiled_in=)`):
read back, a model is the one MuJoCo compiles from its files, and its episodes are the same;
any change to a file the model reads, or another MuJoCo, finds no kept model."""

from __future__ import annotations

import shutil

import mujoco
import numpy as np

from mjtrial import REPO_ROOT
from mjtrial.files.layout import COMPILED_MODELS
from mjtrial.provenance import model_sha256
from mjtrial.sim.physics import compiled_sha256, keep_compiled_models, load_model

LIFT = REPO_ROOT / "models" / "robosuite_lift" / "lift.xml"  # robosuite's, meshes and textures
MANIPULATOR = REPO_ROOT / "tests" / "models" / "dm_manipulator"  # dm_control's, includes


def no_compiling(monkeypatch):
    def refuse(*args, **kwargs):
        raise AssertionError("compiled the model again")

    monkeypatch.setattr(mujoco.MjModel, "from_xml_path", staticmethod(refuse))


def episode(model: mujoco.MjModel, steps: int = 400) -> np.ndarray:
    """qpos after `steps` physics steps under fixed random controls within range."""
    data = mujoco.MjData(model)
    lo, hi = model.actuator_ctrlrange.T
    ctrl = np.random.default_rng(0).uniform(lo, hi, (steps, model.nu))
    for u in ctrl:
        data.ctrl[:] = u
        mujoco.mj_step(model, data)
    return data.qpos.copy()


def test_a_kept_model_is_the_compiled_one_and_runs_the_same_episode(tmp_path, monkeypatch):
    compiled = load_model(LIFT, compiled_in=tmp_path)
    kept = sorted(tmp_path.iterdir())
    assert [p.name for p in kept] == [f"{model_sha256(LIFT)}.mujoco-{mujoco.__version__}.mjb"]
    no_compiling(monkeypatch)
    read = load_model(LIFT, compiled_in=tmp_path)
    assert compiled_sha256(read) == compiled_sha256(compiled)
    fresh = mujoco.MjModel.from_binary_path(str(kept[0]))  # what MuJoCo itself reads back
    assert compiled_sha256(fresh) == compiled_sha256(compiled)
    # the compile with no kept folder, independently: same episode, bit for bit
    monkeypatch.undo()
    np.testing.assert_array_equal(episode(read), episode(load_model(LIFT)))
    assert episode(read).tobytes() == episode(compiled).tobytes()


def test_a_changed_included_file_is_compiled_again(tmp_path):
    folder = tmp_path / "manipulator"
    shutil.copytree(MANIPULATOR, folder)
    scene = folder / "manipulator.xml"
    kept = tmp_path / "kept"
    before = load_model(scene, compiled_in=kept)
    materials = folder / "common" / "materials.xml"
    old = 'name="self" rgba=".7 .5 .3 1"'
    assert old in materials.read_text()
    materials.write_text(materials.read_text().replace(old, 'name="self" rgba="0 0 1 1"'))
    after = load_model(scene, compiled_in=kept)
    assert len(list(kept.iterdir())) == 2
    self_material = mujoco.mj_name2id(after, mujoco.mjtObj.mjOBJ_MATERIAL, "self")
    np.testing.assert_array_equal(after.mat_rgba[self_material], [0, 0, 1, 1])
    assert compiled_sha256(after) != compiled_sha256(before)


def test_a_kept_file_mujoco_cannot_read_is_compiled_again_and_replaced(tmp_path):
    scene = MANIPULATOR / "manipulator.xml"
    reference = load_model(scene)
    kept = tmp_path / f"{model_sha256(scene)}.mujoco-{mujoco.__version__}.mjb"
    kept.write_bytes(b"not a model")
    model = load_model(scene, compiled_in=tmp_path)
    assert compiled_sha256(model) == compiled_sha256(reference)
    assert compiled_sha256(mujoco.MjModel.from_binary_path(str(kept))) == compiled_sha256(reference)


def test_the_workflows_processes_keep_models_where_the_layout_says(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    scene = MANIPULATOR / "manipulator.xml"
    keep_compiled_models(COMPILED_MODELS)
    try:
        load_model(scene)
    finally:
        keep_compiled_models(None)
    assert [p.parent for p in (tmp_path / COMPILED_MODELS).iterdir()] == [
        tmp_path / COMPILED_MODELS
    ]
    load_model(scene, compiled_in=None)  # no folder named: nothing more kept
    assert len(list((tmp_path / COMPILED_MODELS).iterdir())) == 1


def test_without_a_folder_nothing_is_kept_or_read(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)

    def refuse(*args, **kwargs):
        raise AssertionError("read a kept model")

    monkeypatch.setattr(mujoco.MjModel, "from_binary_path", staticmethod(refuse))
    load_model(MANIPULATOR / "manipulator.xml")
    assert list(tmp_path.iterdir()) == []
