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


def _shape(
    shapes: dict[int, _Instances],
    gtype: int,
    size: np.ndarray,
    pos: np.ndarray,
    quat: np.ndarray,
    rgba: np.ndarray,
) -> bool:
    """Add a primitive (a geom's or a site's) to its archetype's instances; False: no such."""
    boxes, ellipsoids = shapes[_G.mjGEOM_BOX], shapes[_G.mjGEOM_ELLIPSOID]
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
        shapes[gtype].add(start, quat, rgba, lengths=2 * size[1], radii=size[0])
    elif gtype == _G.mjGEOM_CYLINDER:  # both centred on the origin along local z
        shapes[gtype].add(pos, quat, rgba, lengths=2 * size[1], radii=size[0])
    else:
        return False
    return True


def body_geometry(model: mujoco.MjModel, body: int, *, meshes: bool = True) -> list[Any]:
    """Archetypes drawing the visible geoms and sites of `body` in the body frame (one per
    geom type).

    Each geom is drawn in its MuJoCo colour (the material's unless the geom sets its own
    rgba); planes as flat boxes whose top face is the plane; all meshes as one `Mesh3D`
    (left out with `meshes` False: `body_meshes` draws them). A site is drawn as MuJoCo's
    viewer draws it by default (a goal marker): in a visible group and not transparent.
    """
    shapes = {
        _G.mjGEOM_BOX: _Instances(rr.Boxes3D, "centers"),
        _G.mjGEOM_ELLIPSOID: _Instances(rr.Ellipsoids3D, "centers"),
        _G.mjGEOM_CAPSULE: _Instances(rr.Capsules3D, "translations"),
        _G.mjGEOM_CYLINDER: _Instances(rr.Cylinders3D, "centers"),
    }
    for g in np.flatnonzero(model.geom_bodyid == body):
        g = int(g)
        if int(model.geom_group[g]) not in VISIBLE_GEOM_GROUPS:
            continue
        gtype = int(model.geom_type[g])
        size, pos, quat = model.geom_size[g], model.geom_pos[g], model.geom_quat[g]
        if gtype == _G.mjGEOM_MESH or _shape(shapes, gtype, size, pos, quat, _geom_rgba(model, g)):
            continue
        name = mujoco.mjtGeom(gtype).name
        label = describe(model, "geom", g)
        warnings.warn(f"{label} ({name}): no rerun equivalent, not drawn", stacklevel=3)
    for s in np.flatnonzero(model.site_bodyid == body):
        s = int(s)
        if int(model.site_group[s]) not in VISIBLE_GEOM_GROUPS or model.site_rgba[s][3] <= 0:
            continue
        size, pos, quat = model.site_size[s], model.site_pos[s], model.site_quat[s]
        _shape(shapes, int(model.site_type[s]), size, pos, quat, _rgba8(model.site_rgba[s]))

    out: list[Any] = []
    with strict():
        for instances in shapes.values():
            out.extend(instances.drawn())
    if meshes:
        out.extend(body_meshes(model, body))
    return out


def body_meshes(model: mujoco.MjModel, body: int) -> list[Any]:
    """One `Mesh3D` drawing all visible mesh geoms of `body` in the body frame, or nothing.

    Vertices are moved into the body frame; one colour for all when the geoms share it.
    """
    vertices: list[np.ndarray] = []
    triangles: list[np.ndarray] = []
    colors: list[np.ndarray] = []
    n_vertices = 0
    for g in np.flatnonzero(model.geom_bodyid == body):
        g = int(g)
        if (
            int(model.geom_group[g]) not in VISIBLE_GEOM_GROUPS
            or int(model.geom_type[g]) != _G.mjGEOM_MESH
        ):
            continue
        pos, quat = model.geom_pos[g], model.geom_quat[g]
        mesh = int(model.geom_dataid[g])
        v0, nv = int(model.mesh_vertadr[mesh]), int(model.mesh_vertnum[mesh])
        f0, nf = int(model.mesh_faceadr[mesh]), int(model.mesh_facenum[mesh])
        vertices.append(pos + _rotated(quat, model.mesh_vert[v0 : v0 + nv]))
        triangles.append(model.mesh_face[f0 : f0 + nf] + n_vertices)
        colors.append(np.broadcast_to(_geom_rgba(model, g), (nv, 4)))
        n_vertices += nv
    if not vertices:
        return []
    color = np.concatenate(colors)
    single = bool(np.all(color == color[0]))
    with strict():
        return [
            rr.Mesh3D(
                vertex_positions=np.concatenate(vertices),
                triangle_indices=np.concatenate(triangles),
                albedo_factor=color[0] if single else None,
                vertex_colors=None if single else color,
            )
        ]


def mesh_scene(model: mujoco.MjModel) -> list[tuple[str, list[Any]]]:
    """(entity, archetypes) that `static_scene` leaves out with `meshes` False, on the same
    entities: each body's `Mesh3D`, and the static pose of a body that holds only meshes and
    bodies like it (a robot's fixed covers), which nothing else needs."""
    elsewhere = _needed_bodies(model, meshes=False)
    items = []
    for b, needed in enumerate(_needed_bodies(model)):
        archetypes = body_meshes(model, b)
        if b and needed and not elsewhere[b]:  # a body without joints: elsewhere has those
            archetypes.insert(0, _static_pose(model, b))
        if archetypes:
            items.append((body_entity(model, b) if b else WORLD, archetypes))
    return items


def _needed_bodies(model: mujoco.MjModel, *, meshes: bool = True) -> np.ndarray:
    """(nbody,) bool: the body, or one below it, draws a geom (a mesh only with `meshes`) or
    a site, moves or is mocap."""
    needed = np.zeros(model.nbody, dtype=bool)
    visible = np.isin(model.geom_group, VISIBLE_GEOM_GROUPS)
    if not meshes:
        visible &= model.geom_type != _G.mjGEOM_MESH
    needed[model.geom_bodyid[visible]] = True
    sites = np.isin(model.site_group, VISIBLE_GEOM_GROUPS) & (model.site_rgba[:, 3] > 0)
    needed[model.site_bodyid[sites]] = True
    needed |= (model.body_jntnum > 0) | (model.body_mocapid >= 0)
    for b in range(model.nbody - 1, 0, -1):  # a parent's id is lower than its children's
        needed[model.body_parentid[b]] |= needed[b]
    return needed


def _static_pose(model: mujoco.MjModel, body: int) -> Any:
    """A body's constant pose in its parent."""
    with strict():
        return rr.Transform3D(
            translation=model.body_pos[body],
            quaternion=mujoco_to_rerun_quat(model.body_quat[body]),
        )


def static_scene(
    model: mujoco.MjModel, *, meshes: bool = True, moving_mocap: bool = False
) -> list[tuple[str, list[Any]]]:
    """(entity, archetypes) logged statically: view coordinates, geoms, poses that never change.

    The world body's geoms go on ``world``; a body without joints gets its pose in its parent
    here, once (a body with joints gets it per step, `BodyPoses`). So does a mocap body: every
    reset takes its pose from the model, which is the episode's own when a state parameter
    moves it (`MocapPosition`), unless the policy moves it (`moving_mocap`: its pose is then
    logged per step, and a static one would hide it). With `meshes` False,
    mesh geoms are left out, and so is the pose of a body that holds only meshes and bodies
    like it (`mesh_scene` has them). A body that draws nothing, with nothing drawn or moving
    below it (a camera's frame), is left out: its pose would cost each recording a chunk (a
    few kB) for nothing to see.
    """
    with strict():
        world = [rr.ViewCoordinates(xyz=rr.ViewCoordinates.RIGHT_HAND_Z_UP)]
    items: list[tuple[str, list[Any]]] = [
        (WORLD, [*world, *body_geometry(model, 0, meshes=meshes)])
    ]
    needed = _needed_bodies(model, meshes=meshes)
    for b in range(1, model.nbody):
        if not needed[b]:
            continue
        archetypes = body_geometry(model, b, meshes=meshes)
        if model.body_jntnum[b] == 0 and not (moving_mocap and model.body_mocapid[b] >= 0):
            archetypes.insert(0, _static_pose(model, b))
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
