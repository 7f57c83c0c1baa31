"""The scene of a recording: MuJoCo's geoms as rerun archetypes, and the bodies' poses.

Each body is an entity nested as MuJoCo's body tree (`names.body_entity`) holding its pose in
its parent body, so the viewer composes the poses as MuJoCo does. Its visible geoms are
instances of one archetype per geom type on its entity, posed in the body frame: an entity per
geom would cost every recording a chunk of its own.
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass
from typing import Any

import mujoco
import numpy as np
import rerun as rr

from mjtrial.recording.arrow import strict
from mjtrial.recording.names import WORLD, body_entity
from mjtrial.task.address import describe

# Geoms in these groups are drawn: the ones MuJoCo's viewer shows by default. Groups 3-5 hold,
# by convention, collision duplicates and helpers that the viewer hides.
VISIBLE_GEOM_GROUPS = (0, 1, 2)
INFINITE_PLANE_HALF_SIZE = 5.0  # m, drawn for a MuJoCo plane of size 0 (infinite)
PLANE_THICKNESS = 1e-3  # m, planes are drawn as flat boxes whose top face is the plane
_DEFAULT_GEOM_RGBA = (0.5, 0.5, 0.5, 1.0)
_IDENTITY = np.array([1.0, 0.0, 0.0, 0.0])  # w-x-y-z


def mujoco_to_rerun_quat(q_wxyz: np.ndarray) -> np.ndarray:
    """Quaternions (..., 4) from MuJoCo's w-x-y-z order to rerun's x-y-z-w order."""
    q = np.asarray(q_wxyz)
    if q.shape[-1:] != (4,):
        raise ValueError(f"expected quaternions of shape (..., 4), got {q.shape}")
    return q[..., [1, 2, 3, 0]]


def rerun_to_mujoco_quat(q_xyzw: np.ndarray) -> np.ndarray:
    """Quaternions (..., 4) from rerun's x-y-z-w order back to MuJoCo's w-x-y-z order."""
    q = np.asarray(q_xyzw)
    if q.shape[-1:] != (4,):
        raise ValueError(f"expected quaternions of shape (..., 4), got {q.shape}")
    return q[..., [3, 0, 1, 2]]


def _rotated(quat: np.ndarray, vectors: np.ndarray) -> np.ndarray:
    """Vectors (..., 3) rotated by one w-x-y-z quaternion (4,), with MuJoCo's rotation matrix."""
    matrix = np.empty(9)
    mujoco.mju_quat2Mat(matrix, np.asarray(quat, dtype=np.float64))
    return np.asarray(vectors, dtype=np.float64) @ matrix.reshape(3, 3).T


# --------------------------------------------------------------------------------------------
# Geometry
# --------------------------------------------------------------------------------------------


def _rgba8(rgba: np.ndarray) -> np.ndarray:
    return np.clip(np.rint(np.asarray(rgba, dtype=np.float64) * 255.0), 0, 255).astype(np.uint8)


def _geom_rgba(model: mujoco.MjModel, g: int) -> np.ndarray:
    """MuJoCo's rule: a material's colour applies unless the geom sets its own rgba."""
    mat = int(model.geom_matid[g])
    rgba = model.geom_rgba[g]
    if mat >= 0 and np.allclose(rgba, _DEFAULT_GEOM_RGBA):
        rgba = model.mat_rgba[mat]
    return _rgba8(rgba)


class _Instances:
    """Geoms of one archetype on one body: per-instance pose (in the body), colour and sizes.

    `archetype` is the rerun class, `position_field` its name for the instances' positions;
    the sizes are added under the archetype's own argument names.
    """

    def __init__(self, archetype: type, position_field: str) -> None:
        self.archetype, self.position_field = archetype, position_field
        self.positions: list[np.ndarray] = []
        self.quats: list[np.ndarray] = []  # w-x-y-z
        self.colors: list[np.ndarray] = []
        self.sizes: dict[str, list[Any]] = {}

    def add(self, pos: np.ndarray, quat: np.ndarray, rgba: np.ndarray, **sizes: Any) -> None:
        self.positions.append(np.asarray(pos, dtype=np.float64))
        self.quats.append(np.asarray(quat, dtype=np.float64))
        self.colors.append(rgba)
        for key, value in sizes.items():
            self.sizes.setdefault(key, []).append(value)

    def pose(self) -> dict[str, np.ndarray]:
        """Pose components, leaving out the ones that are identity for every instance."""
        out: dict[str, np.ndarray] = {}
        positions, quats = np.array(self.positions), np.array(self.quats)
        if np.any(positions != 0.0):
            out[self.position_field] = positions
        if np.any(quats != _IDENTITY):
            out["quaternions"] = mujoco_to_rerun_quat(quats)
        return out

    def drawn(self) -> list[Any]:
        """The archetype drawing these geoms, or nothing when there are none."""
        if not self.colors:
            return []
        return [self.archetype(**self.sizes, colors=self.colors, **self.pose())]


_G = mujoco.mjtGeom


def body_geometry(model: mujoco.MjModel, body: int) -> list[Any]:
    """Archetypes drawing the visible geoms of `body` in the body frame (one per geom type).

    Each geom is drawn in its MuJoCo colour (the material's unless the geom sets its own
    rgba); planes as flat boxes whose top face is the plane; all meshes as one `Mesh3D`.
    """
    boxes = _Instances(rr.Boxes3D, "centers")
    ellipsoids = _Instances(rr.Ellipsoids3D, "centers")
    capsules = _Instances(rr.Capsules3D, "translations")
    cylinders = _Instances(rr.Cylinders3D, "centers")
    mesh_vertices: list[np.ndarray] = []
    mesh_triangles: list[np.ndarray] = []
    mesh_colors: list[np.ndarray] = []
    n_vertices = 0
    for g in np.flatnonzero(model.geom_bodyid == body):
        g = int(g)
        if int(model.geom_group[g]) not in VISIBLE_GEOM_GROUPS:
            continue
        gtype = int(model.geom_type[g])
        size, pos, quat = model.geom_size[g], model.geom_pos[g], model.geom_quat[g]
        rgba = _geom_rgba(model, g)
        if gtype == _G.mjGEOM_BOX:
            boxes.add(pos, quat, rgba, half_sizes=size.copy())
        elif gtype == _G.mjGEOM_PLANE:
            half = [s if s > 0 else INFINITE_PLANE_HALF_SIZE for s in size[:2]]
            top = pos + _rotated(quat, [0.0, 0.0, -PLANE_THICKNESS / 2])
            boxes.add(top, quat, rgba, half_sizes=[half[0], half[1], PLANE_THICKNESS / 2])
        elif gtype == _G.mjGEOM_SPHERE:
            ellipsoids.add(pos, quat, rgba, half_sizes=[size[0]] * 3)
        elif gtype == _G.mjGEOM_ELLIPSOID:
            ellipsoids.add(pos, quat, rgba, half_sizes=size.copy())
        elif gtype == _G.mjGEOM_CAPSULE:
            # MuJoCo: centred on the geom origin along local z, half-length size[1];
            # rerun: from the instance origin along +z.
            start = pos + _rotated(quat, [0.0, 0.0, -size[1]])
            capsules.add(start, quat, rgba, lengths=2 * size[1], radii=size[0])
        elif gtype == _G.mjGEOM_CYLINDER:  # both centred on the origin along local z
            cylinders.add(pos, quat, rgba, lengths=2 * size[1], radii=size[0])
        elif gtype == _G.mjGEOM_MESH:  # one Mesh3D for all meshes: vertices moved into the body
            mesh = int(model.geom_dataid[g])
            v0, nv = int(model.mesh_vertadr[mesh]), int(model.mesh_vertnum[mesh])
            f0, nf = int(model.mesh_faceadr[mesh]), int(model.mesh_facenum[mesh])
            mesh_vertices.append(pos + _rotated(quat, model.mesh_vert[v0 : v0 + nv]))
            mesh_triangles.append(model.mesh_face[f0 : f0 + nf] + n_vertices)
            mesh_colors.append(np.broadcast_to(rgba, (nv, 4)))
            n_vertices += nv
        else:
            name = mujoco.mjtGeom(gtype).name
            label = describe(model, "geom", g)
            warnings.warn(f"{label} ({name}): no rerun equivalent, not drawn", stacklevel=3)

    out: list[Any] = []
    with strict():
        for shapes in (boxes, ellipsoids, capsules, cylinders):
            out.extend(shapes.drawn())
        if mesh_vertices:
            colors = np.concatenate(mesh_colors)
            single = bool(np.all(colors == colors[0]))
            out.append(
                rr.Mesh3D(
                    vertex_positions=np.concatenate(mesh_vertices),
                    triangle_indices=np.concatenate(mesh_triangles),
                    albedo_factor=colors[0] if single else None,
                    vertex_colors=None if single else colors,
                )
            )
    return out


def static_scene(model: mujoco.MjModel) -> list[tuple[str, list[Any]]]:
    """(entity, archetypes) logged statically: view coordinates, geoms, poses that never change.

    The world body's geoms go on ``world``; a body without joints gets its pose in its parent
    here, once (a body with joints gets it per step, `BodyPoses`). So does a mocap body: every
    reset takes its pose from the model, which is the episode's own when a state parameter
    moves it (`MocapPosition`), and no control of an episode moves it.
    """
    with strict():
        world = [rr.ViewCoordinates(xyz=rr.ViewCoordinates.RIGHT_HAND_Z_UP)]
    items: list[tuple[str, list[Any]]] = [(WORLD, [*world, *body_geometry(model, 0)])]
    for b in range(1, model.nbody):
        archetypes = body_geometry(model, b)
        if model.body_jntnum[b] == 0:
            with strict():
                pose = rr.Transform3D(
                    translation=model.body_pos[b],
                    quaternion=mujoco_to_rerun_quat(model.body_quat[b]),
                )
            archetypes.insert(0, pose)
        if archetypes:
            items.append((body_entity(model, b), archetypes))
    return items


# --------------------------------------------------------------------------------------------
# Poses
# --------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class MovingBody:
    """A body with joints, whose pose in its parent body is logged at every logged step."""

    body: int
    entity: str
    rotates: bool  # its orientation in the parent is logged: it changes, or is not the identity


class BodyPoses:
    """Each moving body's pose in its parent body, for many joint configurations at once.

    The pose MuJoCo's `mj_kinematics` computes, in the parent's frame. Bodies that only slide
    and free bodies at the top of the tree have it in closed form from qpos and
    the model's constants (`body_pos`, `body_quat` and the joints' axes, rotated by MuJoCo),
    computed over all rows at once. Other bodies (hinge and ball joints) take it from
    `mj_kinematics` run on each row, which costs a few microseconds a row: as much as all the
    rest of an episode's logging for a few hundred rows.
    """

    def __init__(self, model: mujoco.MjModel) -> None:
        self.model = model
        moving = []
        self._slides: dict[int, tuple[list[int], np.ndarray]] = {}  # qpos addresses, axes
        self._free: dict[int, int] = {}  # qpos address
        self._other: list[int] = []
        for b in range(1, model.nbody):
            first = int(model.body_jntadr[b])
            joints = range(first, first + int(model.body_jntnum[b]))
            if not joints:
                continue  # its pose in the parent is logged once, static (`static_scene`)
            types = {int(model.jnt_type[j]) for j in joints}
            rotates = True
            if types == {mujoco.mjtJoint.mjJNT_SLIDE}:
                axes = _rotated(model.body_quat[b], model.jnt_axis[list(joints)])
                self._slides[b] = ([int(model.jnt_qposadr[j]) for j in joints], axes)
                rotates = bool(np.any(model.body_quat[b] != _IDENTITY))
            elif types == {mujoco.mjtJoint.mjJNT_FREE} and model.body_parentid[b] == 0:
                self._free[b] = int(model.jnt_qposadr[first])
            else:
                self._other.append(b)
            moving.append(MovingBody(b, body_entity(model, b), rotates))
        self.moving = tuple(moving)
        self._data = mujoco.MjData(model) if self._other else None

    def __call__(self, qpos: np.ndarray) -> list[tuple[np.ndarray, np.ndarray | None]]:
        """Poses in the parent body of each of `moving`, from qpos `(n, nq)`.

        Returns:
          per moving body: its position `(n, 3)`, and its w-x-y-z orientation `(n, 4)`, or
          None for a body that does not rotate.
        """
        model = self.model
        n = qpos.shape[0]
        others = self._by_mj_kinematics(qpos)
        out: list[tuple[np.ndarray, np.ndarray | None]] = []
        for m in self.moving:
            b = m.body
            if b in self._slides:
                addresses, axes = self._slides[b]
                pos = model.body_pos[b] + (qpos[:, addresses] - model.qpos0[addresses]) @ axes
                quat = np.broadcast_to(model.body_quat[b], (n, 4)) if m.rotates else None
                out.append((pos, quat))
            elif b in self._free:  # in the world frame, the parent's, as MuJoCo reads qpos
                adr = self._free[b]
                quat = qpos[:, adr + 3 : adr + 7]
                out.append((qpos[:, adr : adr + 3], quat / np.linalg.norm(quat, axis=1)[:, None]))
            else:
                out.append(others[b])
        return out

    def _by_mj_kinematics(self, qpos: np.ndarray) -> dict[int, tuple[np.ndarray, np.ndarray]]:
        """{body: its position `(n, 3)` and orientation `(n, 4)` in its parent} of `_other`."""
        model, data = self.model, self._data
        n = qpos.shape[0]
        out = {b: (np.empty((n, 3)), np.empty((n, 4))) for b in self._other}
        if data is None:
            return out
        parent_pos, parent_quat = np.empty(3), np.empty(4)  # the inverse of the parent's pose
        for i, row in enumerate(qpos):
            data.qpos[:] = row
            mujoco.mj_kinematics(model, data)
            for b, (pos, quat) in out.items():
                parent = model.body_parentid[b]
                mujoco.mju_negPose(parent_pos, parent_quat, data.xpos[parent], data.xquat[parent])
                mujoco.mju_mulPose(
                    pos[i], quat[i], parent_pos, parent_quat, data.xpos[b], data.xquat[b]
                )
        return out
