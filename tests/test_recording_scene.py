"""Tests for the scene of a recording: quaternions, body poses, geoms, and the rerun version."""

from __future__ import annotations

import mujoco
import numpy as np
import pytest
import rerun as rr
from gantry_lift.protocol import control_sequence
from gantry_lift.simulate import iter_episode_batches
from gantry_lift.states import InitialState

from mjtrial import model_path
from mjtrial.recording import logged_steps, mujoco_to_rerun_quat, rerun_to_mujoco_quat
from mjtrial.recording.arrow import archetype_columns, check_rerun_version, chunks
from mjtrial.recording.scene import BodyPoses, static_scene
from mjtrial.sim.physics import load_model

# --------------------------------------------------------------------------------------------
# Quaternions
# --------------------------------------------------------------------------------------------


def test_quaternion_90_degrees_about_z() -> None:
    c = s = np.sqrt(0.5)
    np.testing.assert_array_equal(mujoco_to_rerun_quat(np.array([c, 0, 0, s])), [0, 0, s, c])
    np.testing.assert_array_equal(rerun_to_mujoco_quat(np.array([0, 0, s, c])), [c, 0, 0, s])


def test_quaternion_matches_mujoco_rotation() -> None:
    # the converted quaternion rotates x onto y, as MuJoCo's does
    q = np.empty(4)
    mujoco.mju_axisAngle2Quat(q, np.array([0.0, 0.0, 1.0]), np.pi / 2)
    x, y, z, w = mujoco_to_rerun_quat(q)
    v = np.array([1.0, 0.0, 0.0])
    u = np.array([x, y, z])
    rotated = v + 2 * w * np.cross(u, v) + 2 * np.cross(u, np.cross(u, v))
    np.testing.assert_allclose(rotated, [0.0, 1.0, 0.0], atol=1e-15)


def test_quaternion_round_trip_vectorised() -> None:
    q = np.random.default_rng(0).normal(size=(5, 7, 4))
    xyzw = mujoco_to_rerun_quat(q)
    assert xyzw.shape == q.shape
    np.testing.assert_array_equal(xyzw[..., 3], q[..., 0])
    np.testing.assert_array_equal(rerun_to_mujoco_quat(xyzw), q)
    with pytest.raises(ValueError, match=r"\(\.\.\., 4\)"):
        mujoco_to_rerun_quat(np.zeros((3, 3)))


# --------------------------------------------------------------------------------------------
# Body poses: each in its parent, checked against MuJoCo's world poses
# --------------------------------------------------------------------------------------------


def _mj_kinematics(model: mujoco.MjModel, qpos: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    data = mujoco.MjData(model)
    xpos, xquat = [], []
    for row in qpos:
        data.qpos[:] = row
        mujoco.mj_kinematics(model, data)
        xpos.append(data.xpos.copy())
        xquat.append(data.xquat.copy())
    return np.array(xpos), np.array(xquat)


def _assert_poses_compose_to_mujocos(model: mujoco.MjModel, qpos: np.ndarray) -> None:
    """parent's world pose * pose in the parent = the body's world pose, as MuJoCo has them."""
    poses = BodyPoses(model)
    xpos, xquat = _mj_kinematics(model, qpos)
    got = poses(qpos)
    assert [m.body for m in poses.moving] == [
        b for b in range(1, model.nbody) if model.body_jntnum[b] > 0
    ]
    for m, (pos, quat) in zip(poses.moving, got, strict=True):
        assert pos.shape == (len(qpos), 3)
        if quat is None:
            assert not m.rotates
            quat = np.broadcast_to([1.0, 0.0, 0.0, 0.0], (len(qpos), 4))
        parent = model.body_parentid[m.body]
        for row in range(len(qpos)):
            world_pos, world_quat = np.empty(3), np.empty(4)
            mujoco.mju_mulPose(
                world_pos, world_quat, xpos[row, parent], xquat[row, parent], pos[row], quat[row]
            )
            np.testing.assert_allclose(world_pos, xpos[row, m.body], rtol=0, atol=1e-12)
            np.testing.assert_allclose(world_quat, xquat[row, m.body], rtol=0, atol=1e-12)


@pytest.fixture(scope="module")
def gantry() -> mujoco.MjModel:
    return load_model(model_path("gantry_gripper"))


def test_gantry_poses_match_mujoco_along_an_episode(gantry: mujoco.MjModel) -> None:
    state = InitialState(0, 0.004, -0.002, 0.20, 0.45)
    [batch] = iter_episode_batches(gantry, [state], lift_time=0.15, nthread=1)
    physics = batch.physics[0]
    steps = logged_steps(len(control_sequence(0.15, timestep=gantry.opt.timestep)[0]), 50)
    _assert_poses_compose_to_mujocos(gantry, physics[steps, 1 : 1 + gantry.nq])


def test_gantry_poses_match_mujoco_anywhere(gantry: mujoco.MjModel) -> None:
    qpos = np.random.default_rng(3).normal(size=(20, gantry.nq))  # quaternions unnormalised
    _assert_poses_compose_to_mujocos(gantry, qpos)


def test_only_the_cube_rotates_in_its_parent(gantry: mujoco.MjModel) -> None:
    # the carriage and the fingers slide: no quaternion to log, every step
    rotates = {m.entity: m.rotates for m in BodyPoses(gantry).moving}
    assert rotates == {
        "world/carriage": False,
        "world/carriage/left_finger": False,
        "world/carriage/right_finger": False,
        "world/cube": True,
    }


ARTICULATED = """
<mujoco>
  <worldbody>
    <body name="base" pos="0.1 0.2 0.3" quat="0.9 0.1 0.3 0.2">
      <joint name="slide" type="slide" axis="1 1 0" ref="0.05"/>
      <geom type="sphere" size="0.05"/>
      <body name="arm" pos="0 0.1 0" euler="0.3 0 0.5">
        <joint name="hinge" type="hinge" axis="0 1 1" pos="0.02 0 0.01" ref="0.4"/>
        <geom type="capsule" size="0.01 0.05"/>
        <body name="wrist" pos="0.1 0 0">
          <joint name="ball" type="ball" pos="0 0.01 0"/>
          <joint name="slide2" type="slide" axis="0 0 1"/>
          <geom type="box" size="0.01 0.02 0.03"/>
          <body name="hand" pos="0 0 0.05" euler="0.1 0.2 0.3">
            <joint name="slide3" type="slide" axis="0 1 0"/>
            <geom type="box" size="0.01 0.01 0.01"/>
          </body>
        </body>
      </body>
    </body>
    <body name="free" pos="1 0 0">
      <freejoint/>
      <geom type="box" size="0.1 0.1 0.1"/>
    </body>
  </worldbody>
</mujoco>
"""


def test_poses_match_mujoco_for_all_joint_types() -> None:
    # slides under a turning parent, hinge, ball, free; qpos0 != 0 (ref), quaternions unnormalised
    model = mujoco.MjModel.from_xml_string(ARTICULATED)
    qpos = np.random.default_rng(1).normal(size=(6, model.nq))
    _assert_poses_compose_to_mujocos(model, qpos)


def test_logged_steps() -> None:
    np.testing.assert_array_equal(logged_steps(4, 1), [0, 1, 2, 3])
    np.testing.assert_array_equal(logged_steps(10, 5), [4, 9])
    np.testing.assert_array_equal(logged_steps(12, 5), [4, 9, 11])  # the last step always
    np.testing.assert_array_equal(logged_steps(3, 5), [2])
    assert len(logged_steps(1425, 5)) == 285
    with pytest.raises(ValueError, match="log_every"):
        logged_steps(10, 0)
    with pytest.raises(TypeError, match="log_every"):
        logged_steps(10, 2.0)  # type: ignore[arg-type]


# --------------------------------------------------------------------------------------------
# Geometry
# --------------------------------------------------------------------------------------------

PRIMITIVES = """
<mujoco>
  <asset>
    <material name="red" rgba="1 0 0 1"/>
    <mesh name="tet" vertex="0 0 0  1 0 0  0 1 0  0 0 1"/>
  </asset>
  <worldbody>
    <geom name="ground" type="plane" size="0 0 1" material="red"/>
    <body name="b">
      <freejoint/>
      <geom name="ball" type="sphere" size="0.1" material="red" rgba="0 1 0 1"/>
      <geom name="capsule" type="capsule" size="0.05 0.2" pos="0 0 1" euler="60 0 0"/>
      <geom type="cylinder" size="0.05 0.2"/>
      <geom type="ellipsoid" size="0.1 0.2 0.3"/>
      <geom name="tetrahedron" type="mesh" mesh="tet" pos="0 0 2" euler="0 30 0"/>
      <geom name="hidden" type="box" size="1 1 1" group="3"/>
    </body>
    <body name="post" pos="1 2 0" euler="0 0 0.5">
      <geom type="box" size="0.1 0.1 0.5" pos="0 0 0.5"/>
    </body>
  </worldbody>
</mujoco>
"""


def _column(batch, name: str) -> list:
    return batch.column(batch.schema.names.index(name)).to_pylist()


def _rotate(quat: np.ndarray, v) -> np.ndarray:
    out = np.zeros(3)
    mujoco.mju_rotVecQuat(out, np.asarray(v, dtype=np.float64), quat)
    return out


def test_every_primitive_type_is_drawn() -> None:
    model = mujoco.MjModel.from_xml_string(PRIMITIVES)
    columns = [c for e, a in static_scene(model) for c in archetype_columns(e, a)]
    static = {chunk.entity_path: chunk.to_record_batch() for chunk in chunks(columns)}
    assert set(static) == {"/world", "/world/b", "/world/post"}
    world, b, post = static["/world"], static["/world/b"], static["/world/post"]
    # the world body's plane: a flat box on ``world`` whose top face is the plane
    assert _column(world, "Boxes3D:colors") == [[0xFF0000FF]]
    assert _column(world, "Boxes3D:half_sizes") == [[pytest.approx([5.0, 5.0, 5e-4])]]
    assert _column(world, "Boxes3D:centers") == [[pytest.approx([0.0, 0.0, -5e-4])]]
    # one archetype per geom type on the body, each geom an instance; group 3 is not drawn
    assert not any(name.startswith("Boxes3D:") for name in b.schema.names)
    assert _column(b, "Ellipsoids3D:half_sizes") == [
        [pytest.approx([0.1] * 3), pytest.approx([0.1, 0.2, 0.3])]
    ]
    assert _column(b, "Ellipsoids3D:colors")[0][0] == 0x00FF00FF  # the geom's own rgba wins
    assert _column(b, "Cylinders3D:lengths") == [[pytest.approx(0.4)]]
    # a capsule runs from its start, MuJoCo's centre minus its half-length along its axis
    capsule = model.geom("capsule")
    axis = _rotate(capsule.quat, [0.0, 0.0, 1.0])
    [[start]] = _column(b, "Capsules3D:translations")
    np.testing.assert_allclose(start, capsule.pos - 0.2 * axis, atol=1e-6)
    [[quat]] = _column(b, "Capsules3D:quaternions")
    np.testing.assert_allclose(quat, mujoco_to_rerun_quat(capsule.quat), atol=1e-6)
    # meshes: vertices moved into the body frame
    [vertices] = _column(b, "Mesh3D:vertex_positions")
    mesh = model.geom("tetrahedron")
    v0, nv = model.mesh_vertadr[0], model.mesh_vertnum[0]
    expected = np.array([mesh.pos + _rotate(mesh.quat, v) for v in model.mesh_vert[v0 : v0 + nv]])
    np.testing.assert_allclose(vertices, expected, atol=1e-6)
    assert len(_column(b, "Mesh3D:triangle_indices")[0]) == model.mesh_facenum[0]
    # a body without joints gets its pose in the parent once, static
    [[translation]] = _column(post, "Transform3D:translation")
    np.testing.assert_allclose(translation, model.body("post").pos, atol=1e-6)
    [[rotation]] = _column(post, "Transform3D:quaternion")
    np.testing.assert_allclose(rotation, mujoco_to_rerun_quat(model.body("post").quat), atol=1e-6)
    [[center]] = _column(post, "Boxes3D:centers")
    np.testing.assert_allclose(center, [0.0, 0.0, 0.5], atol=1e-6)


# --------------------------------------------------------------------------------------------
# The rerun-sdk version the chunk encoding was written for
# --------------------------------------------------------------------------------------------


def test_another_rerun_version_is_refused_with_a_clear_error() -> None:
    check_rerun_version(rr.__version__)  # the installed one: imports at all
    with pytest.raises(RuntimeError, match=r"written for rerun-sdk 0\.41\.0, found 0\.42\.0"):
        check_rerun_version("0.42.0")
