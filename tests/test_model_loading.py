"""A model loads one way in every stage, and its hashes are functions of its files alone.

Third-party models come as vendors ship them: a scene in a task folder including an arm file in
a sub-folder, which includes its own common file and names meshes in a mesh folder. MuJoCo 3.14
resolves such a nested include against the working folder when the scene's path is relative;
and `MjSpec.to_xml()` writes meshes' `content_type` on its first call in a process only.
"""

from __future__ import annotations

import hashlib
import struct
import subprocess
import sys
from pathlib import Path

import mujoco
import numpy as np
import pyarrow.parquet as pq
import pytest

from mjtrial import REPO_ROOT, provenance
from mjtrial.provenance.model_closure import model_closure
from mjtrial.sim.physics import ModelError, compiled_sha256, load_model, load_spec
from mjtrial.stages.rollout import run_shard
from mjtrial.stages.states import build_states
from mjtrial.studies.variants import nominal_model_hash, variant_model

pytestmark = pytest.mark.end_to_end

CARTPOLE = REPO_ROOT / "tasks" / "cartpole_latency" / "cartpole.xml"


def _tetrahedron_stl(path: Path) -> None:
    """A binary STL of a 10 cm tetrahedron."""
    corners = [(0, 0, 0), (0.1, 0, 0), (0, 0.1, 0), (0, 0, 0.1)]
    faces = [(0, 2, 1), (0, 1, 3), (0, 3, 2), (1, 2, 3)]
    path.parent.mkdir(parents=True, exist_ok=True)
    with open(path, "wb") as fh:
        fh.write(b"\0" * 80 + struct.pack("<I", len(faces)))
        for face in faces:
            fh.write(struct.pack("<3f", 0, 0, 0))
            for corner in face:
                fh.write(struct.pack("<3f", *corners[corner]))
            fh.write(b"\0\0")


def vendor_layout(root: Path) -> Path:
    """`tasks/reach/scene.xml` including `arm/arm.xml`, which includes `common.xml` (in `arm/`)
    and names `meshes/link.stl` (in `arm/`), as dm_control's third-party arms are laid out."""
    task = root / "tasks" / "reach"
    (task / "arm").mkdir(parents=True)
    _tetrahedron_stl(task / "arm" / "meshes" / "link.stl")
    (task / "scene.xml").write_text(
        '<mujoco model="reach">\n  <include file="arm/arm.xml"/>\n'
        '  <worldbody><geom name="floor" type="plane" size="1 1 0.1"/></worldbody>\n</mujoco>\n'
    )
    (task / "arm" / "arm.xml").write_text(
        '<mujoco>\n  <include file="common.xml"/>\n  <worldbody>\n'
        '    <body name="link" pos="0 0 0.2"><joint name="hinge" axis="0 1 0"/>\n'
        '      <geom name="link" type="mesh" mesh="link"/></body>\n  </worldbody>\n</mujoco>\n'
    )
    (task / "arm" / "common.xml").write_text(
        '<mujoco>\n  <asset><mesh name="link" file="meshes/link.stl"/></asset>\n</mujoco>\n'
    )
    return task / "scene.xml"


def test_a_vendor_layout_loads_from_a_relative_path(tmp_path, monkeypatch):
    scene = vendor_layout(tmp_path)
    monkeypatch.chdir(tmp_path)
    relative = scene.relative_to(tmp_path)
    absolute = mujoco.MjModel.from_xml_path(str(scene))  # MuJoCo itself, from the full path
    for model in (
        load_model(relative),
        load_spec(relative).compile(),
        variant_model(relative, {})[0],
    ):
        assert model.nmesh == 1
        np.testing.assert_array_equal(model.mesh_vert, absolute.mesh_vert)
    assert compiled_sha256(load_model(relative)) == compiled_sha256(absolute)


def test_the_model_files_of_a_vendor_layout_are_the_same_from_either_path(tmp_path, monkeypatch):
    scene = vendor_layout(tmp_path)
    monkeypatch.chdir(tmp_path)
    expected = sorted(
        (scene.parent / name).resolve()
        for name in ("arm/arm.xml", "arm/common.xml", "arm/meshes/link.stl")
    )
    assert model_closure(scene.relative_to(tmp_path))[1:] == expected
    assert model_closure(scene)[1:] == expected
    assert provenance.model_sha256(scene.relative_to(tmp_path)) == provenance.model_sha256(scene)


def test_a_model_that_cannot_load_is_one_line_naming_the_file(tmp_path, monkeypatch):
    scene = vendor_layout(tmp_path)
    (scene.parent / "arm" / "common.xml").unlink()
    monkeypatch.chdir(tmp_path)
    with pytest.raises(ModelError) as caught:
        load_model(scene.relative_to(tmp_path))
    message = str(caught.value)
    assert message.startswith("tasks/reach/scene.xml: MuJoCo could not compile the model:")
    assert "\n" not in message and str(tmp_path) not in message


_HASH_IN_A_FRESH_PROCESS = """
import sys, mujoco
from mjtrial.studies.variants import nominal_model_hash, variant_model
scene = sys.argv[1]
if sys.argv[2] == "to_xml first":
    mujoco.MjSpec.from_file(scene).to_xml()
print(nominal_model_hash(scene), nominal_model_hash(scene))
print(variant_model(scene, {"geom": {"link": {"friction": [0.5, 0.01, 0.001]}}})[1])
"""


def test_a_model_hash_is_the_same_in_every_process_order_and_folder(tmp_path):
    """The first `MjSpec.to_xml()` of a process differs from the later ones; the hashes must
    not, nor depend on where the files lie."""
    here = vendor_layout(tmp_path / "a")
    there = vendor_layout(tmp_path / "b")
    outputs = {
        subprocess.run(
            [sys.executable, "-c", _HASH_IN_A_FRESH_PROCESS, str(scene), order],
            capture_output=True,
            text=True,
            check=True,
        ).stdout
        for scene in (here, there)
        for order in ("hash first", "to_xml first")
    }
    assert len(outputs) == 1
    [output] = outputs
    nominal_first, nominal_again, variant = output.split()
    assert nominal_first == nominal_again != variant
    # MuJoCo's own MJB file, the mesh's absolute path (kept for an asset of an included file)
    # blanked: what lies in the file, not where
    mjb = tmp_path / "model.mjb"
    mujoco.mj_saveModel(mujoco.MjModel.from_xml_path(str(here)), str(mjb), None)
    mesh = str(here.parent / "arm" / "meshes" / "link.stl").encode()
    assert mjb.read_bytes().count(mesh) == 1
    blanked = mjb.read_bytes().replace(mesh, b"\0" * len(mesh))
    assert nominal_first == hashlib.sha256(blanked).hexdigest()


def test_an_unedited_variant_is_the_committed_model_bit_for_bit():
    """The edited spec is compiled as it is: a round trip through `to_xml()` put the
    cart-pole's pole quaternion 6e-17 away from the committed model's."""
    committed = mujoco.MjModel.from_xml_path(str(CARTPOLE))
    model, digest = variant_model(CARTPOLE, {})
    for name in ("body_iquat", "geom_quat", "body_quat", "geom_size", "dof_armature"):
        np.testing.assert_array_equal(getattr(model, name), getattr(committed, name))
    assert digest == nominal_model_hash(CARTPOLE) == compiled_sha256(committed)


def test_a_vendor_layout_with_a_meshdir_runs_through_the_pipeline(tmp_path, monkeypatch):
    """A task on a scene whose `meshdir` names a mesh folder below it and whose arm file, in a
    sub-folder, includes the file declaring the mesh: its states and a rollout shard (recorded,
    mesh drawn) are built from relative paths, as Snakemake's jobs run, and each episode ends
    where a plain `mj_step` loop on MuJoCo's own load of the full path ends it."""
    task = tmp_path / "tasks" / "push"
    (task / "arm").mkdir(parents=True)
    _tetrahedron_stl(task / "arm" / "meshes" / "block.stl")
    (task / "scene.xml").write_text(
        '<mujoco model="push">\n  <compiler meshdir="arm/meshes"/>\n'
        '  <include file="arm/arm.xml"/>\n'
        '  <worldbody><geom name="floor" type="plane" size="1 1 0.1"/></worldbody>\n</mujoco>\n'
    )
    (task / "arm" / "arm.xml").write_text(
        '<mujoco>\n  <include file="common.xml"/>\n  <worldbody>\n'
        '    <body name="block" pos="0 0 0.2">\n'
        '      <joint name="block_slide" type="slide" axis="1 0 0" damping="2"/>\n'
        '      <geom type="mesh" mesh="block" mass="1" contype="0" conaffinity="0"/>\n'
        "    </body>\n  </worldbody>\n"
        '  <actuator><motor name="pusher" joint="block_slide" ctrlrange="-10 10"/></actuator>\n'
        "</mujoco>\n"
    )
    (task / "arm" / "common.xml").write_text(
        '<mujoco>\n  <asset><mesh name="block" file="block.stl"/></asset>\n</mujoco>\n'
    )
    template = REPO_ROOT / "src" / "mjtrial" / "templates" / "new_task" / "task.py"
    (task / "task.py").write_text(
        template.read_text().replace('model="model.xml"', 'model="scene.xml"')
    )
    monkeypatch.chdir(tmp_path)
    states = Path("results/push/states.parquet")
    table = Path("results/push/rollouts/firm/shard-00000.parquet")
    reference = "tasks/push/task.py"
    build_states(
        states_slice={
            "n": 3,
            "seed": 1,
            "development_seed": 2,
            "ranges": {"mass": [0.5, 3.0], "start": [-0.05, 0.05]},
            "task": reference,
        },
        output=states,
        repo_root=tmp_path,
    )
    condition = {"push_force": 2.0, "push_time": 0.5}
    rows = run_shard(
        condition_slice={
            "condition": "firm",
            "task": reference,
            **condition,
            "failure_taxonomy": {},
            "recording": {"rate_hz": 20, "episodes": "all"},
        },
        states_path=states,
        model_file=Path("tasks/push/scene.xml"),
        first=0,
        stop=3,
        output_table=table,
        output_recording=table.with_suffix(""),
        nthread=1,
        rule="rollout:firm#00000",
        repo_root=tmp_path,
    ).to_pylist()
    # one recording per episode, and the model's mesh drawn once for the folder (`meshes.rrd`)
    assert len(list(table.with_suffix("").glob("firm-state-*.rrd"))) == 3
    assert (table.with_suffix("") / "meshes.rrd").is_file()
    model = mujoco.MjModel.from_xml_path(str(task / "scene.xml"))
    assert model.nmesh == 1
    for state, row in zip(pq.read_table(states).to_pylist(), rows, strict=True):
        m = mujoco.MjModel.from_xml_path(str(task / "scene.xml"))
        d = mujoco.MjData(m)
        m.body_mass[m.body("block").id] = state["mass"]
        mujoco.mj_setConst(m, d)
        mujoco.mj_resetData(m, d)
        d.qpos[0] += state["start"]
        for step in range(round(3.0 / m.opt.timestep)):  # the template's 3 s episode
            d.ctrl[0] = condition["push_force"] if step < round(0.5 / m.opt.timestep) else 0.0
            mujoco.mj_step(m, d)
        assert row["final_position"] == d.qpos[0]
