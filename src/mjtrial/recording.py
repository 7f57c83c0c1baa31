"""Rerun recordings of episodes: the one module that talks to rerun.

Why rerun: an episode's outcome is a handful of numbers, but *why* a grasp failed is only visible
in its motion. Every condition gets a folder holding one ``.rrd`` per episode (one recording
each) and a ``blueprint.rbl``; the failed episodes of all conditions are gathered into one
``failures.rrd``.

Layout of a recording (entity paths are built only here, by the constants and functions below):

* ``world``: view coordinates (z up) and the geoms of MuJoCo's world body (the floor), static.
* ``world/<body>``, nested as MuJoCo's body tree (``world/carriage/left_finger``): the body's
  pose *in its parent body* per logged step (``Transform3D``; a body without joints gets it
  once, static) and, static, its visible geoms: one archetype per geom type (``Boxes3D`` for
  boxes and planes, ``Ellipsoids3D`` for spheres and ellipsoids, ``Capsules3D``,
  ``Cylinders3D``, one ``Mesh3D`` for all its meshes) whose instances are the geoms, each posed
  in the body frame and drawn in MuJoCo's colour.
* the signals (``Scalars``), on the entity of the body they belong to, named by a static
  ``SeriesLines``: ``cube_height`` on the cube; ``finger_opening`` and the control targets
  ``ctrl_x``, ``ctrl_y``, ``ctrl_z``, ``ctrl_gripper`` on the fingers' parent (the carriage);
  ``left_normal_force`` and ``right_normal_force`` on the bodies of the pads (the fingers).
* recording properties ``episode`` (one struct: condition, state id and parameters, success,
  final height, failure category or null, ``log_every``, ``n_steps``) and ``provenance`` (the
  stamp as JSON, see :mod:`mjtrial.provenance`).

Time series use one timeline, ``sim_time``: simulated seconds, stored by rerun as integer
nanoseconds. `default_blueprint` lays out the scene beside plots of the cube height and of the
contact forces: a condition's folder holds it as ``blueprint.rbl``; ``failures.rrd`` and a
replay's file hold it themselves.

Why this shape: size, and the time it takes to write. In a file, every entity costs each
recording a chunk of its own (~1-2 kB of schema even for one box), and every time-series chunk
16 bytes of row id and 8 of timestamp per row; every (entity, component) pair costs each
recording ~0.5 kB of index in the file's footer, which ``ChunkStore.write_rrd`` builds (and
``rerun rrd route`` decodes and encodes again) for every recording. So geoms are instances of one
archetype on their body's entity, not entities of their own; the signals share their body's
time-series chunk; the episode's fields are one struct; solid shapes are a default of the 3D
view rather than a component of each shape; and a child body's pose in its parent keeps its
constant components constant (the fingers only slide along y), which compresses well.

Writing a condition's folder (`write_condition_recordings`): the main thread only keeps each
episode's logged rows; a writer thread builds the recordings of `_GROUP` episodes at once,
straight from Arrow columns (``Chunk.from_record_batch``, with the columns' layouts prepared
once, and the chunks every recording shares built once and given a fresh chunk id per
recording), and writes each with ``ChunkStore.write_rrd``, while the main thread runs the next
rollouts (``mujoco.rollout`` releases the GIL); a third thread fsyncs the files. Why a file per
episode, see `write_condition_recordings`.

Writing several recordings into one file (``failures.rrd``, a replay with its blueprint): each
is encoded with ``ChunkStore.write_rrd`` into the stdin of ``rerun rrd route`` (the CLI in the
rerun-sdk wheel), which writes them as one stream with one valid footer. Plain concatenation is
not enough: rerun 0.41's reader and ``rerun rrd verify`` reject concatenated files, and files
without a footer. (A blueprint sent into a recording's stream can make ``route`` panic, so the
blueprint travels as a stream of its own.) The CLI runs with ``CI`` set, the only environment
switch of rerun 0.41 that stops it from writing analytics files under the home folder. (rerun
0.41's ``route`` panics when given its own output as input: combine these files with
``rerun rrd merge`` instead.)
"""

from __future__ import annotations

import functools
import importlib.util
import json
import os
import queue
import shutil
import subprocess
import sys
import tempfile
import threading
import warnings
from collections.abc import Callable, Iterable, Iterator, Mapping, Sequence
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import IO, Any

import mujoco
import numpy as np
import pyarrow as pa
import pyarrow.compute as pc
import rerun as rr
import rerun.blueprint as rrb
from rerun.chunk import Chunk, ChunkStore, RrdReader, StoreEntry
from rerun.error_utils import catch_and_log_exceptions

from mjtrial.atomic import atomic_directory, atomic_path, fsync_file
from mjtrial.protocol import CTRL_GRIPPER, CTRL_X, CTRL_Y, CTRL_Z
from mjtrial.provenance import RECORDING_FOLDER_BLUEPRINT
from mjtrial.simulate import CUBE_BODY, FULLPHYSICS, STATE_QPOS, STATE_TIME, InitialState

__all__ = [
    "APPLICATION_ID",
    "TIMELINE",
    "EpisodeRecord",
    "body_entity",
    "body_poses",
    "default_blueprint",
    "episode_file_name",
    "episode_recording_id",
    "episode_recording_name",
    "list_recordings",
    "log_episode",
    "log_model_geometry",
    "logged_steps",
    "mujoco_to_rerun_quat",
    "read_episode",
    "read_rrd_stamp",
    "recording_files",
    "rerun_to_mujoco_quat",
    "write_condition_recordings",
    "write_episode_recording",
    "write_failures_rrd",
]

# --------------------------------------------------------------------------------------------
# Names: every entity path, timeline and property name lives here
# --------------------------------------------------------------------------------------------

APPLICATION_ID = "mjtrial"
TIMELINE = "sim_time"
WORLD = "world"
# Signals, logged on the entity of the body they belong to, so they share its time-series chunk
# (an entity of their own would cost every recording a chunk of row ids and timestamps): the
# cube's height on the cube; the mean finger opening and the control targets on the fingers'
# parent (the carriage); each pad's normal force on the pad's body (the fingers).
CUBE_SERIES = ("cube_height",)
CTRL_SERIES = ("ctrl_x", "ctrl_y", "ctrl_z", "ctrl_gripper")
_CTRL_COLUMNS = (CTRL_X, CTRL_Y, CTRL_Z, CTRL_GRIPPER)
GRIPPER_SERIES = ("finger_opening", *CTRL_SERIES)
CONTACT_SERIES = ("left_normal_force", "right_normal_force")
SIGNALS = (*CUBE_SERIES, *GRIPPER_SERIES, *CONTACT_SERIES)  # in `_Chunker.series`'s order
FAILURES_SUMMARY = "failures"  # recording id and entity of failures.rrd's summary

EPISODE_PROPERTY = "episode"
PROVENANCE_PROPERTY = "provenance"
SOURCE_PROVENANCE_PROPERTY = "source_provenance"
FAILURES_PROPERTY = "failures"
_JSON_FIELD = "json"
_PROPERTIES = "/" + rr.RECORDING_PROPERTIES_PATH.strip("/")  # entity of recording properties
_NAME_COMPONENT = "RecordingInfo:name"
_FAILURE_PREFIX = "failures-"  # recording ids of episodes copied into failures.rrd

# Model names the plots read (models/gantry_gripper/gantry_gripper.xml).
FINGER_JOINTS = ("left_finger", "right_finger")
CONTACT_SENSORS = ("left_pad_cube", "right_pad_cube")  # data="found force": [found, fx, fy, fz]
CONTACT_NORMAL_AXIS = 1  # the pads face each other along world y: normal force = |F_y|

# Geoms in these groups are drawn: the ones MuJoCo's viewer shows by default. Groups 3-5 hold,
# by convention, collision duplicates and helpers that the viewer hides.
VISIBLE_GEOM_GROUPS = (0, 1, 2)
INFINITE_PLANE_HALF_SIZE = 5.0  # m, drawn for a MuJoCo plane of size 0 (infinite)
PLANE_THICKNESS = 1e-3  # m, planes are drawn as flat boxes whose top face is the plane
_DEFAULT_GEOM_RGBA = (0.5, 0.5, 0.5, 1.0)


def _part(name: str) -> str:
    return rr.escape_entity_path_part(name)


def _body_name(model: mujoco.MjModel, body_id: int) -> str:
    return model.body(body_id).name or f"body_{body_id}"


def body_entity(model: mujoco.MjModel, body_id: int) -> str:
    """Entity path of a body: its parent's path, then its name (or ``body_<i>``).

    MuJoCo's world body is ``world``, so the gantry's fingers are ``world/carriage/left_finger``.
    """
    parts = []
    while body_id != 0:
        parts.append(_part(_body_name(model, body_id)))
        body_id = int(model.body_parentid[body_id])
    return "/".join([WORLD, *reversed(parts)])


def episode_recording_id(condition: str, state_id: int) -> str:
    """Deterministic recording id, so reruns of the same episode are comparable."""
    return f"{condition}-state-{int(state_id):06d}"


def episode_recording_name(condition: str, state_id: int) -> str:
    """Recording name shown in the viewer."""
    return f"{condition} / state {int(state_id)}"


# Shapes drawn solid, as in MuJoCo's viewer. Set as defaults of the 3D view rather than logged
# with the shapes: a component logged costs every recording ~0.5 kB in the file's footer.
SOLID_SHAPES = (rr.Boxes3D, rr.Ellipsoids3D, rr.Capsules3D, rr.Cylinders3D)

# (entity, series) of the gantry gripper's signals, for a blueprint made without the model.
GANTRY_SIGNALS = (
    ("world/cube", CUBE_SERIES),
    ("world/carriage", GRIPPER_SERIES),
    ("world/carriage/left_finger", CONTACT_SERIES[:1]),
    ("world/carriage/right_finger", CONTACT_SERIES[1:]),
)


def default_blueprint(
    signals: Sequence[tuple[str, Sequence[str]]] = GANTRY_SIGNALS,
) -> rrb.Blueprint:
    """Viewer layout: the scene on the left, cube height and contact forces on the right.

    Args:
      signals: (entity, series names) of the logged signals. The upper plot shows the entities
        of the cube's height, the finger opening and the control targets (m); the lower one
        those of the pads' normal forces (N). The scene's view draws shapes solid (rerun's
        default for boxes is a wireframe).
    """
    force = [e for e, names in signals if set(names) & set(CONTACT_SERIES)]
    lift = [e for e, names in signals if e not in force]
    solid = [shape.from_fields(fill_mode=rr.components.FillMode.Solid) for shape in SOLID_SHAPES]
    return rrb.Blueprint(
        rrb.Horizontal(
            rrb.Spatial3DView(origin=WORLD, name="scene", defaults=solid),
            rrb.Vertical(
                rrb.TimeSeriesView(
                    origin=WORLD,
                    contents=[f"+ /{e.strip('/')}" for e in lift],
                    name="cube height, finger opening, ctrl (m)",
                ),
                rrb.TimeSeriesView(
                    origin=WORLD,
                    contents=[f"+ /{e.strip('/')}" for e in force],
                    name="pad-cube normal force (N)",
                ),
            ),
            column_shares=[3, 2],
        )
    )


# --------------------------------------------------------------------------------------------
# Quaternions and kinematics
# --------------------------------------------------------------------------------------------


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


def _cross(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Cross product over the last axis (np.cross costs ~20 us per call on small inputs)."""
    a0, a1, a2 = a[..., 0], a[..., 1], a[..., 2]
    b0, b1, b2 = b[..., 0], b[..., 1], b[..., 2]
    return np.stack([a1 * b2 - a2 * b1, a2 * b0 - a0 * b2, a0 * b1 - a1 * b0], axis=-1)


def _quat_mul(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Hamilton product of w-x-y-z quaternions, broadcast over leading axes."""
    aw, ax, ay, az = a[..., 0], a[..., 1], a[..., 2], a[..., 3]
    bw, bx, by, bz = b[..., 0], b[..., 1], b[..., 2], b[..., 3]
    return np.stack(
        [
            aw * bw - ax * bx - ay * by - az * bz,
            aw * bx + ax * bw + ay * bz - az * by,
            aw * by - ax * bz + ay * bw + az * bx,
            aw * bz + ax * by - ay * bx + az * bw,
        ],
        axis=-1,
    )


def _quat_rotate(q: np.ndarray, v: np.ndarray) -> np.ndarray:
    """Rotate vectors v (..., 3) by unit w-x-y-z quaternions q (..., 4)."""
    u = q[..., 1:]
    t = 2.0 * _cross(u, v)
    return v + q[..., :1] * t + _cross(u, t)


def _normalize(q: np.ndarray) -> np.ndarray:
    return q / np.linalg.norm(q, axis=-1, keepdims=True)


_IDENTITY = np.array([1.0, 0.0, 0.0, 0.0])  # w-x-y-z
_CONJUGATE = np.array([1.0, -1.0, -1.0, -1.0])

_FREE, _BALL, _SLIDE, _HINGE = (
    int(mujoco.mjtJoint.mjJNT_FREE),
    int(mujoco.mjtJoint.mjJNT_BALL),
    int(mujoco.mjtJoint.mjJNT_SLIDE),
    int(mujoco.mjtJoint.mjJNT_HINGE),
)


def _body_frames(
    model: mujoco.MjModel, qpos: np.ndarray
) -> tuple[list[np.ndarray], list[np.ndarray]]:
    """Per body: position ((3,) if constant, else (n, 3)) and w-x-y-z orientation ((4,) or (n, 4)).

    Follows `mj_kinematics` (engine_core_smooth.c) step by step over all rows at once. Values
    that do not depend on qpos stay unbroadcast, which keeps the gantry's pure translations cheap
    and tells the logger which bodies never rotate.
    """
    pos: list[np.ndarray] = [np.zeros(3)]
    quat: list[np.ndarray] = [np.array([1.0, 0.0, 0.0, 0.0])]
    for i in range(1, model.nbody):
        jnt0, njnt = int(model.body_jntadr[i]), int(model.body_jntnum[i])
        if njnt == 1 and int(model.jnt_type[jnt0]) == _FREE:
            adr = int(model.jnt_qposadr[jnt0])
            pos.append(qpos[:, adr : adr + 3])
            quat.append(_normalize(qpos[:, adr + 3 : adr + 7]))
            continue
        if model.body_mocapid[i] >= 0:
            raise ValueError(f"body {_body_name(model, i)!r} is a mocap body: not supported")
        parent = int(model.body_parentid[i])
        p = pos[parent] + _quat_rotate(quat[parent], model.body_pos[i])
        q = _quat_mul(quat[parent], model.body_quat[i])
        for j in range(jnt0, jnt0 + njnt):
            adr = int(model.jnt_qposadr[j])
            jtype = int(model.jnt_type[j])
            if jtype == _SLIDE:
                dq = (qpos[:, adr] - model.qpos0[adr])[:, None]
                p = p + _quat_rotate(q, model.jnt_axis[j]) * dq
            elif jtype in (_HINGE, _BALL):
                anchor = _quat_rotate(q, model.jnt_pos[j]) + p
                if jtype == _BALL:
                    qloc = _normalize(qpos[:, adr : adr + 4])
                else:
                    half = (0.5 * (qpos[:, adr] - model.qpos0[adr]))[:, None]
                    qloc = np.concatenate([np.cos(half), np.sin(half) * model.jnt_axis[j]], axis=1)
                q = _quat_mul(q, qloc)
                p = anchor - _quat_rotate(q, model.jnt_pos[j])
            else:
                raise ValueError(f"body {_body_name(model, i)!r}: unsupported joint type {jtype}")
        pos.append(p)
        quat.append(_normalize(q))
    return pos, quat


def _in_parent(
    pos: np.ndarray,
    quat: np.ndarray,
    parent_pos: np.ndarray,
    parent_quat: np.ndarray,
    *,
    turns: bool = True,
) -> tuple[np.ndarray, np.ndarray]:
    """Pose of a body in its parent's frame, from both world poses (w-x-y-z unit quaternions).

    With `turns` False the parent's orientation is the identity: only the positions subtract.
    """
    pos = pos - parent_pos
    if not turns:
        return pos, quat
    inverse = parent_quat * _CONJUGATE
    return _quat_rotate(inverse, pos), _quat_mul(inverse, quat)


def body_poses(model: mujoco.MjModel, qpos: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """World poses of all bodies for many configurations: MuJoCo's `mj_kinematics`, vectorised.

    One `mj_kinematics` call per logged step costs more Python overhead than the whole logging
    budget, so the recursion runs in numpy over all rows at once. Hinge and slide joints move
    relative to `qpos0`, as in MuJoCo; mocap bodies are not supported (their poses are not part
    of the physics state).

    Args:
      model: the model.
      qpos: (n, nq) joint positions.

    Returns:
      xpos: (n, nbody, 3) body positions; xquat: (n, nbody, 4) w-x-y-z body orientations.
    """
    qpos = np.asarray(qpos, dtype=np.float64)
    if qpos.ndim != 2 or qpos.shape[1] != model.nq:
        raise ValueError(f"qpos: expected shape (n, {model.nq}), got {qpos.shape}")
    pos, quat = _body_frames(model, qpos)
    n = qpos.shape[0]
    xpos = np.empty((n, model.nbody, 3))
    xquat = np.empty((n, model.nbody, 4))
    for i in range(model.nbody):
        xpos[:, i] = pos[i]
        xquat[:, i] = quat[i]
    return xpos, xquat


# --------------------------------------------------------------------------------------------
# What gets logged
# --------------------------------------------------------------------------------------------


@contextmanager
def _strict() -> Iterator[None]:
    """Make rerun raise on misuse inside this block instead of warning and dropping data."""
    with catch_and_log_exceptions(context="mjtrial.recording", strict=True):
        yield


def _rgba8(rgba: np.ndarray) -> np.ndarray:
    return np.clip(np.rint(np.asarray(rgba, dtype=np.float64) * 255.0), 0, 255).astype(np.uint8)


def _geom_rgba(model: mujoco.MjModel, g: int) -> np.ndarray:
    """MuJoCo's rule: a material's colour applies unless the geom sets its own rgba."""
    mat = int(model.geom_matid[g])
    rgba = model.geom_rgba[g]
    if mat >= 0 and np.allclose(rgba, _DEFAULT_GEOM_RGBA):
        rgba = model.mat_rgba[mat]
    return _rgba8(rgba)


_G = mujoco.mjtGeom
_BOX, _PLANE, _SPHERE, _ELLIPSOID, _CAPSULE, _CYLINDER, _MESH = (
    int(t)
    for t in (
        _G.mjGEOM_BOX,
        _G.mjGEOM_PLANE,
        _G.mjGEOM_SPHERE,
        _G.mjGEOM_ELLIPSOID,
        _G.mjGEOM_CAPSULE,
        _G.mjGEOM_CYLINDER,
        _G.mjGEOM_MESH,
    )
)


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


def _body_geometry(model: mujoco.MjModel, body: int) -> list[Any]:
    """Archetypes drawing the visible geoms of `body` in the body frame (one per geom type)."""
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
        if gtype == _BOX:
            boxes.add(pos, quat, rgba, half_sizes=size.copy())
        elif gtype == _PLANE:
            half = [s if s > 0 else INFINITE_PLANE_HALF_SIZE for s in size[:2]]
            top = pos + _quat_rotate(quat, np.array([0.0, 0.0, -PLANE_THICKNESS / 2]))
            boxes.add(top, quat, rgba, half_sizes=[half[0], half[1], PLANE_THICKNESS / 2])
        elif gtype == _SPHERE:
            ellipsoids.add(pos, quat, rgba, half_sizes=[size[0]] * 3)
        elif gtype == _ELLIPSOID:
            ellipsoids.add(pos, quat, rgba, half_sizes=size.copy())
        elif gtype == _CAPSULE:
            # MuJoCo: centred on the geom origin along local z, half-length size[1];
            # rerun: from the instance origin along +z.
            start = pos + _quat_rotate(quat, np.array([0.0, 0.0, -size[1]]))
            capsules.add(start, quat, rgba, lengths=2 * size[1], radii=size[0])
        elif gtype == _CYLINDER:  # both centred on the origin along local z
            cylinders.add(pos, quat, rgba, lengths=2 * size[1], radii=size[0])
        elif gtype == _MESH:  # one Mesh3D for all meshes: vertices moved into the body frame
            mesh = int(model.geom_dataid[g])
            v0, nv = int(model.mesh_vertadr[mesh]), int(model.mesh_vertnum[mesh])
            f0, nf = int(model.mesh_faceadr[mesh]), int(model.mesh_facenum[mesh])
            vertices = model.mesh_vert[v0 : v0 + nv].astype(np.float64)
            mesh_vertices.append(pos + _quat_rotate(np.broadcast_to(quat, (nv, 4)), vertices))
            mesh_triangles.append(model.mesh_face[f0 : f0 + nf] + n_vertices)
            mesh_colors.append(np.broadcast_to(rgba, (nv, 4)))
            n_vertices += nv
        else:
            name = mujoco.mjtGeom(gtype).name
            warnings.warn(f"geom {g} ({name}): no rerun equivalent, not drawn", stacklevel=3)

    out: list[Any] = []
    with _strict():
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


def logged_steps(nstep: int, log_every: int) -> np.ndarray:
    """Steps that are logged: every `log_every`-th (1-based), and always the last one."""
    if isinstance(log_every, bool) or not isinstance(log_every, (int, np.integer)):
        raise TypeError(f"log_every: expected an integer, got {log_every!r}")
    if log_every < 1:
        raise ValueError(f"log_every: expected >= 1, got {log_every}")
    if nstep < 1:
        raise ValueError(f"expected at least one step, got {nstep}")
    steps = np.arange(log_every - 1, nstep, log_every)
    if steps.size == 0 or steps[-1] != nstep - 1:
        steps = np.append(steps, nstep - 1)
    return steps


@dataclass(frozen=True)
class _Moving:
    """A body whose pose in its parent changes: what its time series hold."""

    body: int
    entity: str
    parent: int
    rotates: bool  # its orientation in the parent changes (hinge, ball or free joint)
    parent_turns: bool  # its parent's world orientation can differ from the identity


@dataclass(frozen=True)
class _Layout:
    """Where the logged quantities sit in the model's state and sensor vectors."""

    nstate: int
    nsensordata: int
    nu: int
    moving: tuple[_Moving, ...]  # bodies with joints, in body order (the others: static poses)
    # (entity, series names, their columns in SIGNALS) per entity holding signals
    signals: tuple[tuple[str, tuple[str, ...], tuple[int, ...]], ...]
    cube_z: int  # index in the physics state
    fingers: tuple[int, ...]  # indices in the physics state
    contact_normals: tuple[int, ...]  # indices in sensordata

    @classmethod
    def of(cls, model: mujoco.MjModel) -> _Layout:
        def named(kind: mujoco.mjtObj, name: str) -> int:
            i = mujoco.mj_name2id(model, kind, name)
            if i < 0:
                raise ValueError(f"model has no {kind.name[6:].lower()} named {name!r}")
            return i

        cube = named(mujoco.mjtObj.mjOBJ_BODY, CUBE_BODY)
        cube_adr = int(model.jnt_qposadr[model.body_jntadr[cube]])
        fingers = tuple(
            STATE_QPOS + int(model.jnt_qposadr[named(mujoco.mjtObj.mjOBJ_JOINT, j)])
            for j in FINGER_JOINTS
        )
        normals, pads = [], []
        for s in CONTACT_SENSORS:
            sid = named(mujoco.mjtObj.mjOBJ_SENSOR, s)
            if model.sensor_dim[sid] != 4:
                raise ValueError(
                    f"sensor {s!r}: expected 4 values (found, force), got {model.sensor_dim[sid]}"
                )
            if model.sensor_objtype[sid] != mujoco.mjtObj.mjOBJ_GEOM:
                raise ValueError(f"sensor {s!r}: expected a contact sensor of a geom (the pad)")
            normals.append(int(model.sensor_adr[sid]) + 1 + CONTACT_NORMAL_AXIS)
            pads.append(int(model.geom_bodyid[model.sensor_objid[sid]]))
        finger_bodies = [
            int(model.jnt_bodyid[named(mujoco.mjtObj.mjOBJ_JOINT, j)]) for j in FINGER_JOINTS
        ]
        parents = {int(model.body_parentid[b]) for b in finger_bodies}
        if len(parents) != 1:
            raise ValueError(f"joints {FINGER_JOINTS}: expected fingers with one common parent")
        owners = [cube] * len(CUBE_SERIES) + [parents.pop()] * len(GRIPPER_SERIES) + pads
        signals: dict[str, list[int]] = {}  # entity: columns in SIGNALS, in the model's order
        for column, body in sorted(enumerate(owners), key=lambda c: c[1]):
            signals.setdefault(body_entity(model, body), []).append(column)
        # _body_frames keeps an orientation that does not depend on qpos unbroadcast, (4,)
        _, quat = _body_frames(model, model.qpos0[None, :])
        moving = []
        for b in range(1, model.nbody):
            jnt0, njnt = int(model.body_jntadr[b]), int(model.body_jntnum[b])
            if njnt == 0:
                continue  # its pose in the parent is logged once, static (_geometry_items)
            parent = int(model.body_parentid[b])
            turns = quat[parent].ndim == 2 or bool(np.any(quat[parent] != _IDENTITY))
            slides = all(int(model.jnt_type[j]) == _SLIDE for j in range(jnt0, jnt0 + njnt))
            rotates = not slides or bool(np.any(model.body_quat[b] != _IDENTITY))
            moving.append(_Moving(b, body_entity(model, b), parent, rotates, turns))
        return cls(
            nstate=mujoco.mj_stateSize(model, FULLPHYSICS),
            nsensordata=model.nsensordata,
            nu=model.nu,
            moving=tuple(moving),
            signals=tuple(
                (e, tuple(SIGNALS[c] for c in columns), tuple(columns))
                for e, columns in signals.items()
            ),
            cube_z=STATE_QPOS + cube_adr + 2,
            fingers=fingers,
            contact_normals=tuple(normals),
        )


def _geometry_items(model: mujoco.MjModel) -> list[tuple[str, list[Any]]]:
    """(entity, archetypes) logged statically: view coordinates, geoms, poses that never change."""
    items: list[tuple[str, list[Any]]] = [
        (WORLD, [rr.ViewCoordinates(xyz=rr.ViewCoordinates.RIGHT_HAND_Z_UP)])
    ]
    items[0][1].extend(_body_geometry(model, 0))
    for b in range(1, model.nbody):
        archetypes = _body_geometry(model, b)
        if model.body_jntnum[b] == 0:  # its pose in the parent never changes
            with _strict():
                pose = rr.Transform3D(
                    translation=model.body_pos[b],
                    quaternion=mujoco_to_rerun_quat(model.body_quat[b]),
                )
            archetypes.insert(0, pose)
        if archetypes:
            items.append((body_entity(model, b), archetypes))
    return items


def _signal_style_items(layout: _Layout) -> list[tuple[str, list[Any]]]:
    """(entity, archetypes) naming the signals' series."""
    with _strict():
        return [(e, [rr.SeriesLines(names=list(names))]) for e, names, _ in layout.signals]


# Arrow columns tagged with their entity path (rerun:entity_path), so that one record batch can
# describe several entities: `Chunk.from_record_batch` makes one chunk per entity of it.
_Column = tuple[pa.Field, pa.Array]
_ENTITY_KEY = b"rerun:entity_path"


def _tag(field: pa.Field, entity: str) -> pa.Field:
    entity = "/" + entity.lstrip("/")
    metadata = {**(field.metadata or {}), _ENTITY_KEY: entity.encode()}
    return pa.field(f"{entity}:{field.name}", field.type, metadata=metadata)


def _archetype_columns(entity: str, archetypes: Iterable[Any]) -> list[_Column]:
    """One static row holding all components of `archetypes`, as `rec.log(static=True)` would."""
    columns = []
    with _strict():
        for archetype in archetypes:
            for batch in archetype.as_component_batches():
                columns.append(batch.partition([len(batch.as_arrow_array())]))
        chunk = Chunk.from_columns(entity, [], columns)
    record = chunk.to_record_batch()
    return [
        (_tag(field, entity), column)
        for field, column in zip(record.schema, record.columns, strict=True)
        if (field.metadata or {}).get(b"rerun:kind") == b"data"
    ]


def _batch(columns: Sequence[_Column]) -> pa.RecordBatch:
    fields, arrays = zip(*columns, strict=True)
    return pa.RecordBatch.from_arrays(list(arrays), schema=pa.schema(list(fields)))


def _chunks(columns: Sequence[_Column] | pa.RecordBatch, *, temporal: bool = False) -> list[Chunk]:
    """Chunks (fresh ids, one per entity) of columns; temporal ones are indexed by `TIMELINE`."""
    batch = columns if isinstance(columns, pa.RecordBatch) else _batch(columns)
    return Chunk.from_record_batch(batch, index=TIMELINE if temporal else None)


@functools.cache
def _series_fields() -> dict[str, pa.Field]:
    """Arrow field (type and rerun metadata) of each time-series component, as rerun builds it."""
    times = [rr.TimeColumn(TIMELINE, duration=np.zeros(1, dtype="timedelta64[ns]"))]
    with _strict():
        columns = [
            *rr.Transform3D.columns(translation=np.zeros((1, 3)), quaternion=[[0, 0, 0, 1.0]]),
            *rr.Scalars.columns(scalars=np.zeros(1)),
        ]
        record = Chunk.from_columns("template", times, columns).to_record_batch()
    return {field.name: field for field in record.schema}


_TRANSLATION, _QUATERNION, _SCALARS = (
    "Transform3D:translation",
    "Transform3D:quaternion",
    "Scalars:scalars",
)


class _Chunker:
    """A model's recordings as Arrow columns, built fast: the column layouts are prepared once.

    `geometry` and `styles` are the static columns every recording shares (geoms, static poses,
    series names); `series` builds the time series of many episodes at once.
    """

    def __init__(self, model: mujoco.MjModel, layout: _Layout) -> None:
        self.model = model
        self.layout = layout
        self.geometry = [
            c for entity, a in _geometry_items(model) for c in _archetype_columns(entity, a)
        ]
        self.styles = [
            c for entity, a in _signal_style_items(layout) for c in _archetype_columns(entity, a)
        ]
        fields = _series_fields()
        self._time_field = pa.field(TIMELINE, pa.duration("ns"))
        self._pose_fields = [
            (
                _tag(fields[_TRANSLATION], m.entity),
                _tag(fields[_QUATERNION], m.entity) if m.rotates else None,
            )
            for m in layout.moving
        ]
        self._signal_fields = [_tag(fields[_SCALARS], e) for e, _, _ in layout.signals]
        self._offsets: dict[tuple[int, int], pa.Array] = {}

    def _list_offsets(self, n: int, width: int) -> pa.Array:
        key = (n, width)
        if key not in self._offsets:
            self._offsets[key] = pa.array(np.arange(0, n * width + 1, width, dtype=np.int32))
        return self._offsets[key]

    def _list(self, field: pa.Field, values: np.ndarray) -> pa.Array:
        """(n, width) values as a list column of `field`'s type: one row of `width` per step."""
        n, width = values.shape
        item = field.type.value_type
        if pa.types.is_fixed_size_list(item):
            dtype = item.value_type.to_pandas_dtype()
            flat = pa.array(np.ascontiguousarray(values, dtype=dtype).ravel())
            inner = pa.FixedSizeListArray.from_arrays(flat, type=item)
            return pa.ListArray.from_arrays(self._list_offsets(n, 1), inner, type=field.type)
        flat = pa.array(np.ascontiguousarray(values, dtype=np.float64).ravel())
        return pa.ListArray.from_arrays(self._list_offsets(n, width), flat, type=field.type)

    def series(
        self, episodes: Sequence[tuple[np.ndarray, np.ndarray]], ctrl: np.ndarray
    ) -> pa.RecordBatch:
        """Time series of episodes, from each one's logged rows of physics and sensors.

        Args:
          episodes: (rows, sensors) per episode: (n, nstate) physics and (n, nsensordata)
            sensors at the n logged steps, the same n for all.
          ctrl: (n, nu) the ctrl at the logged steps.

        Returns:
          the columns of all episodes, one after another: episode i's are rows i*n to (i+1)*n
          (zero-copy slices). Everything runs once over all episodes' rows: numpy's and
          pyarrow's cost per call, not per row, dominates at a few hundred rows.
        """
        layout = self.layout
        n, k = ctrl.shape[0], len(episodes)
        rows = np.concatenate([r for r, _ in episodes])
        sensors = np.concatenate([s for _, s in episodes])
        time_ns = np.rint(rows[:, STATE_TIME] * 1e9).astype(np.int64).astype("timedelta64[ns]")
        values: list[tuple[pa.Field, np.ndarray]] = []
        positions, orientations = _body_frames(
            self.model, rows[:, STATE_QPOS : STATE_QPOS + self.model.nq]
        )
        for m, (t_field, q_field) in zip(layout.moving, self._pose_fields, strict=True):
            # the pose in the parent body, whose entity holds the parent's pose
            pos, quat = positions[m.body], orientations[m.body]
            if m.parent != 0:
                pos, quat = _in_parent(
                    pos, quat, positions[m.parent], orientations[m.parent], turns=m.parent_turns
                )
            values.append((t_field, np.broadcast_to(pos, (n * k, 3))))
            if q_field is not None:
                values.append((q_field, mujoco_to_rerun_quat(np.broadcast_to(quat, (n * k, 4)))))
        signals = np.empty((n * k, len(SIGNALS)))  # columns: SIGNALS
        signals[:, 0] = rows[:, layout.cube_z]
        signals[:, 1] = rows[:, list(layout.fingers)].mean(axis=1)
        signals[:, 2:6] = np.tile(ctrl[:, list(_CTRL_COLUMNS)], (k, 1))
        signals[:, 6:] = np.abs(sensors[:, list(layout.contact_normals)])
        for field, (_, _, columns) in zip(self._signal_fields, layout.signals, strict=True):
            values.append((field, signals[:, list(columns)]))
        columns = [(self._time_field, pa.array(time_ns))]
        columns += [(field, self._list(field, v)) for field, v in values]
        return _batch(columns)


def _as_trajectory(
    layout: _Layout, physics: Any, sensordata: Any, ctrl: Any
) -> tuple[np.ndarray, ...]:
    ctrl = np.asarray(ctrl, dtype=np.float64)
    physics = np.asarray(physics, dtype=np.float64)
    sensordata = np.asarray(sensordata, dtype=np.float64)
    nstep = ctrl.shape[0] if ctrl.ndim == 2 and ctrl.shape[0] > 0 else 0
    expected = {
        "ctrl": (ctrl, (nstep, layout.nu)),
        "physics": (physics, (nstep, layout.nstate)),
        "sensordata": (sensordata, (nstep, layout.nsensordata)),
    }
    for name, (arr, shape) in expected.items():
        if nstep == 0 or arr.shape != shape:
            raise ValueError(f"{name}: expected shape {shape} (n_steps from ctrl), got {arr.shape}")
    return physics, sensordata, ctrl


def log_model_geometry(rec: rr.RecordingStream, model: mujoco.MjModel) -> None:
    """Log every visible geom (groups 0-2) statically, on its body's entity.

    Each body's geoms become instances of one archetype per geom type, with their pose in the
    body and their MuJoCo colour (the material's unless the geom sets its own rgba); the body
    entity gets the per-step pose (`log_episode`), so the scene moves as MuJoCo's does. Planes
    are drawn as flat boxes; the world body's geoms go on ``world``; a body whose pose cannot
    change gets that pose here.
    """
    columns = [c for entity, a in _geometry_items(model) for c in _archetype_columns(entity, a)]
    with _strict():
        rec.send_chunks(_chunks(columns))


def log_episode(
    rec: rr.RecordingStream,
    model: mujoco.MjModel,
    *,
    physics: np.ndarray,
    sensordata: np.ndarray,
    ctrl: np.ndarray,
    log_every: int,
) -> None:
    """Log one episode's motion and signals: every `log_every`-th step, and the last.

    Body poses come from qpos (`body_poses`), each in its parent body's frame; a body's pose and
    its signals are one chunk on the `sim_time` timeline (= physics[t, 0]); the signals' series
    names are logged statically.

    Args:
      rec: the episode's recording.
      model: the model the episode ran on.
      physics: (n_steps, nstate) mjSTATE_FULLPHYSICS after each step.
      sensordata: (n_steps, nsensordata) sensors after each step.
      ctrl: (n_steps, nu) the ctrl applied at each step.
      log_every: log every `log_every`-th step (>= 1); the last step is always logged.
    """
    layout = _Layout.of(model)
    physics, sensordata, ctrl = _as_trajectory(layout, physics, sensordata, ctrl)
    steps = logged_steps(ctrl.shape[0], log_every)
    chunker = _Chunker(model, layout)
    columns = chunker.series([(physics[steps], sensordata[steps])], ctrl[steps])
    with _strict():
        rec.send_chunks([*_chunks(chunker.styles), *_chunks(columns, temporal=True)])


# --------------------------------------------------------------------------------------------
# Files holding many recordings
# --------------------------------------------------------------------------------------------


@dataclass(frozen=True, eq=False)
class EpisodeRecord:
    """One episode to record: its initial state, trajectories and outcome."""

    state: InitialState
    physics: np.ndarray  # (n_steps, nstate) mjSTATE_FULLPHYSICS after each step
    sensordata: np.ndarray  # (n_steps, nsensordata)
    success: bool
    final_height: float
    failure_category: str | None = None


def _static_chunk(entity: str, archetypes: Iterable[Any]) -> Chunk:
    """One static row holding all components of `archetypes`, as `rec.log(static=True)` would."""
    return _chunks(_archetype_columns(entity, archetypes))[0]


def _property_chunk(name: str, fields: Mapping[str, Any]) -> Chunk:
    # One-element lists: rerun converts bare Python scalars ~10x slower (exception paths).
    values = {k: v if isinstance(v, list) else [v] for k, v in fields.items()}
    with _strict():
        return Chunk.from_property(name, rr.AnyValues(**values))


def _name_chunk(name: str) -> Chunk:
    return _static_chunk(_PROPERTIES, [rr.archetypes.RecordingInfo(name=name)])


def _property_columns(name: str, fields: Mapping[str, Any]) -> list[_Column]:
    """The columns `_property_chunk` would hold (what `rr.send_property` logs), built directly."""
    entity = f"{_PROPERTIES}/{_part(name)}"
    out = []
    for key, value in fields.items():
        if isinstance(value, (bool, np.bool_)):
            arrow_type: pa.DataType = pa.bool_()
        elif isinstance(value, (int, np.integer)):
            arrow_type = pa.int64()
        elif isinstance(value, (float, np.floating)):
            arrow_type = pa.float64()
        elif isinstance(value, str):
            arrow_type = pa.string()
        else:
            raise TypeError(f"property {name}.{key}: unsupported value {value!r}")
        metadata = {b"rerun:kind": b"data", b"rerun:component": key.encode()}
        field = pa.field(key, pa.list_(arrow_type), metadata=metadata)
        out.append((_tag(field, entity), pa.array([[value]], type=field.type)))
    return out


# The `episode` property is one component holding a struct, not one component per field: every
# component costs each recording ~0.5 kB of index in the file's footer. The struct keeps the
# names and types (failure_category is null when the episode did not fail).
EPISODE_COMPONENT = "fields"
_EPISODE_TYPE = pa.struct(
    [
        pa.field("condition", pa.string(), nullable=False),
        pa.field("state_id", pa.int64(), nullable=False),
        pa.field("dx", pa.float64(), nullable=False),
        pa.field("dy", pa.float64(), nullable=False),
        pa.field("yaw", pa.float64(), nullable=False),
        pa.field("mass", pa.float64(), nullable=False),
        pa.field("success", pa.bool_(), nullable=False),
        pa.field("final_height", pa.float64(), nullable=False),
        pa.field("failure_category", pa.string()),
        pa.field("log_every", pa.int64(), nullable=False),
        pa.field("n_steps", pa.int64(), nullable=False),
    ]
)


@functools.cache
def _episode_field() -> pa.Field:
    metadata = {b"rerun:kind": b"data", b"rerun:component": EPISODE_COMPONENT.encode()}
    field = pa.field(EPISODE_COMPONENT, pa.list_(_EPISODE_TYPE), metadata=metadata)
    return _tag(field, f"{_PROPERTIES}/{EPISODE_PROPERTY}")


def _episode_property(fields: Mapping[str, Any]) -> dict[str, Any]:
    """The fields of a recording's `episode` property, read back (`_raw_properties`)."""
    inner = fields.get(EPISODE_COMPONENT)
    return {"failure_category": None, **(inner if isinstance(inner, Mapping) else fields)}


@functools.cache
def _name_field() -> pa.Field:
    (field, _), *_ = _archetype_columns(_PROPERTIES, [rr.archetypes.RecordingInfo(name="")])
    return field


def _stamp_json(stamp: Mapping[str, Any]) -> str:
    if not isinstance(stamp, Mapping) or "mjtrial_stamp" not in stamp:
        raise ValueError(
            "not an mjtrial provenance stamp (missing 'mjtrial_stamp'); use make_stamp"
        )
    return json.dumps(dict(stamp), allow_nan=False)


def _rerun_cli() -> str:
    """The rerun CLI binary shipped in the rerun-sdk wheel (package `rerun_cli`)."""
    spec = importlib.util.find_spec("rerun_cli")
    if spec is not None and spec.submodule_search_locations:
        exe = "rerun.exe" if sys.platform.startswith("win") else "rerun"
        candidate = Path(next(iter(spec.submodule_search_locations))) / exe
        if candidate.is_file():
            return str(candidate)
    found = shutil.which("rerun")
    if found is None:
        raise RuntimeError("the rerun CLI was not found (it ships with rerun-sdk as rerun_cli)")
    return found


def _cli_env() -> dict[str, str]:
    """Environment for the rerun CLI: with `CI` set, rerun 0.41 writes no analytics files."""
    return {**os.environ, "CI": os.environ.get("CI", "1")}


# Niceness added to `rerun rrd route`, a process of its own: at a lower priority than whatever
# else runs, it takes the gaps they leave.
_ROUTE_NICENESS = 10


def _lower_priority(pid: int, niceness: int) -> None:
    """Best effort: raise the niceness of a process."""
    if niceness <= 0:
        return
    try:
        os.setpriority(os.PRIO_PROCESS, pid, os.getpriority(os.PRIO_PROCESS, pid) + niceness)
    except (AttributeError, OSError):  # no setpriority (Windows), or not permitted: run as is
        pass


def _fd_path(fd: int) -> str | None:
    """A path that opens file descriptor `fd` again (Linux, macOS, BSDs), or None."""
    for directory in ("/proc/self/fd", "/dev/fd"):
        if os.path.isdir(directory):
            return f"{directory}/{fd}"
    return None


class _RrdFileWriter:
    """Writes rerun streams, one after another, as one valid .rrd file.

    Feeds them to ``rerun rrd route -o <path>``, which re-frames them as a single stream with one
    footer. Each stream is written by a rerun writer given a path (`write_rrd`, a blueprint's
    `save`): the path of route's stdin where the OS has one, so the stream goes straight into the
    pipe, else a scratch file whose bytes are then copied. Writing blocks while route catches up
    (its stdout goes to /dev/null and its stderr to a file, so route never waits for us).
    """

    def __init__(self, path: Path, scratch: Path) -> None:
        self._stderr: IO[bytes] = tempfile.TemporaryFile()
        self._proc = subprocess.Popen(
            [_rerun_cli(), "rrd", "route", "-o", str(path)],
            stdin=subprocess.PIPE,
            stdout=subprocess.DEVNULL,
            stderr=self._stderr,
            env=_cli_env(),
        )
        _lower_priority(self._proc.pid, _ROUTE_NICENESS)
        assert self._proc.stdin is not None
        self._stdin = self._proc.stdin
        self._direct = _fd_path(self._stdin.fileno())
        self._part = scratch / "stream.rrd"

    def write(self, writer: Callable[[str], None], *, direct: bool = True) -> None:
        """Append the stream that `writer(path)` writes to `path`.

        `direct` False goes through the scratch file even where route's stdin has a path: for
        writers that do not return when the pipe breaks (a blueprint's `save` writes from a
        thread of its own).
        """
        try:
            if direct and self._direct is not None:
                writer(self._direct)
            else:
                writer(str(self._part))
                try:
                    self._stdin.write(self._part.read_bytes())
                    self._stdin.flush()  # before any direct write
                finally:
                    self._part.unlink()
        except Exception as exc:
            if self._proc.poll() is None:
                raise
            # route exited early: the broken pipe is only the symptom
            raise RuntimeError(f"rerun rrd route stopped early: {self._error_text()}") from exc

    def close(self) -> None:
        try:
            try:
                self._stdin.close()
            except OSError:
                pass  # route's exit code and stderr say why
            code = self._proc.wait()
            if code != 0:
                raise RuntimeError(f"rerun rrd route failed (exit {code}): {self._error_text()}")
        finally:
            self._stderr.close()

    def abort(self) -> None:
        self._proc.kill()
        self._proc.wait()
        try:
            self._stdin.close()
        except OSError:
            pass
        self._stderr.close()

    def _error_text(self) -> str:
        self._stderr.seek(0)
        text = self._stderr.read().decode("utf-8", "replace").strip()
        return text[-2000:] or "no output"


@contextmanager
def _rrd_output(
    path: Path, application_id: str, blueprint: rrb.Blueprint
) -> Iterator[_RrdFileWriter]:
    """The writer of `path`'s stream, which starts with `blueprint`."""
    with tempfile.TemporaryDirectory(dir=path.parent, prefix=f".{path.name}.parts-") as scratch:
        writer = _RrdFileWriter(path, Path(scratch))
        try:
            writer.write(
                functools.partial(_save_blueprint, blueprint, application_id), direct=False
            )
            yield writer
        except BaseException:
            writer.abort()
            raise
        writer.close()


def _save_blueprint(blueprint: rrb.Blueprint, application_id: str, path: str) -> None:
    """A blueprint as a stream of its own (an .rbl file), active and default."""
    try:
        blueprint.save(application_id, path)
    except RuntimeError as exc:  # e.g. "Blueprint stream has no store info"
        raise RuntimeError(
            f"rerun could not encode the blueprint ({exc}); is rerun disabled (RERUN=off)?"
        ) from exc


def _write_store(
    out: _RrdFileWriter, store: ChunkStore, *, application_id: str, recording_id: str
) -> None:
    """Append one recording, the chunks of `store`, to `out`.

    Writing a `ChunkStore` needs no GIL, whereas a stream over Python objects takes it for every
    chunk: in a worker thread it would wait for the caller's thread, which holds the GIL while it
    prepares the next rollout.
    """

    def writer(path: str) -> None:
        with _strict():
            store.write_rrd(path, application_id=application_id, recording_id=recording_id)

    out.write(writer)


def _write_recording(
    out: _RrdFileWriter, chunks: Iterable[Chunk], *, application_id: str, recording_id: str
) -> None:
    """Append one recording of `chunks` to `out`."""
    with _strict():
        store = ChunkStore.from_chunks(list(chunks))
    _write_store(out, store, application_id=application_id, recording_id=recording_id)


class _Worker:
    """Runs `job(item)` on each put item, in order, in a thread of its own.

    At most `maxsize` items wait. The first error stops the work and is raised in the caller's
    thread by the next `put` or by `finish`.

    The thread runs at the caller's priority, not below it: building a recording holds the GIL,
    and a thread that holds the GIL at a lower priority, while the simulation's threads fill the
    cores, keeps the caller (which drives the simulation) waiting for it: a priority inversion.
    """

    _STOP = object()

    def __init__(self, job: Callable[[Any], None], *, maxsize: int, name: str) -> None:
        self._job = job
        self._queue: queue.Queue[Any] = queue.Queue(maxsize=maxsize)
        self._error: BaseException | None = None
        self._cancelled = False
        self._thread = threading.Thread(target=self._run, name=name, daemon=True)
        self._thread.start()

    def _run(self) -> None:
        while (item := self._queue.get()) is not self._STOP:
            if self._error is not None or self._cancelled:
                continue  # keep draining, so the producer never blocks on a full queue
            try:
                self._job(item)
            except BaseException as exc:  # raised in the caller's thread
                self._error = exc

    def put(self, item: Any) -> None:
        self._raise()
        self._queue.put(item)

    def finish(self) -> None:
        self._queue.put(self._STOP)
        self._thread.join()
        self._raise()

    def cancel(self) -> None:
        self._cancelled = True
        self._queue.put(self._STOP)
        self._thread.join()

    def _raise(self) -> None:
        if self._error is not None:
            raise self._error


@dataclass(frozen=True)
class _Pending:
    """An episode waiting for its recording to be built: its logged rows and properties."""

    recording_id: str
    name: str
    fields: dict[str, Any]
    rows: np.ndarray  # logged rows of the physics state
    sensors: np.ndarray  # logged rows of sensordata


_GROUP = 32  # episodes whose recordings are built at once (numpy's cost is per call)
_QUEUE = 128  # episodes waiting for the writer thread, at most


def _file_name(recording_id: str) -> str:
    """The file of a recording in its condition's folder: named by its recording id."""
    return f"{recording_id}.rrd"


def episode_file_name(condition: str, state_id: int) -> str:
    """The file of an episode's recording in its condition's folder."""
    return _file_name(episode_recording_id(condition, state_id))


class _EpisodeStores:
    """Builds each episode's recording (a `ChunkStore`) for a model, condition and stamp.

    `groups(episodes)` consumes the episodes one at a time (a generator over rollout batches
    will do) and keeps their logged rows until `_GROUP` have come; `build(group)` then builds
    those recordings at once (numpy's and pyarrow's cost is per call).
    """

    def __init__(
        self,
        *,
        model: mujoco.MjModel,
        condition: str,
        ctrl: np.ndarray,
        stamp: Mapping[str, Any],
        log_every: int,
    ) -> None:
        stamp_text = _stamp_json(stamp)
        self.layout = layout = _Layout.of(model)
        ctrl = np.asarray(ctrl, dtype=np.float64)
        if ctrl.ndim != 2 or ctrl.shape[1] != layout.nu:
            raise ValueError(f"ctrl: expected shape (n_steps, {layout.nu}), got {ctrl.shape}")
        self.condition, self.ctrl, self.log_every = condition, ctrl, log_every
        self.steps = logged_steps(ctrl.shape[0], log_every)  # validate before any work
        self.chunker = _Chunker(model, layout)
        with _strict():
            # the same in every recording: geometry, static poses, series names and the stamp
            self.constant = _chunks(
                [
                    *self.chunker.geometry,
                    *self.chunker.styles,
                    *_property_columns(PROVENANCE_PROPERTY, {_JSON_FIELD: stamp_text}),
                ]
            )
        self.blueprint = default_blueprint([(e, names) for e, names, _ in layout.signals])

    def build(self, group: list[_Pending]) -> Iterator[tuple[str, ChunkStore]]:
        """(recording id, store) of each episode of a group from `groups`."""
        n = len(self.steps)
        series = self.chunker.series([(p.rows, p.sensors) for p in group], self.ctrl[self.steps])
        name_field, episode_field = _name_field(), _episode_field()
        properties = _batch(
            [
                (name_field, pa.array([[p.name] for p in group], type=name_field.type)),
                (episode_field, pa.array([[p.fields] for p in group], type=episode_field.type)),
            ]
        )
        for i, ep in enumerate(group):
            with _strict():
                chunks = [
                    *_chunks(properties.slice(i, 1)),
                    # the same data in every recording, each time under a fresh chunk id
                    *(c.with_entity_path(c.entity_path) for c in self.constant),
                    *_chunks(series.slice(i * n, n), temporal=True),
                ]
                store = ChunkStore.from_chunks(chunks)
            yield ep.recording_id, store

    def groups(self, episodes: Iterable[EpisodeRecord]) -> Iterator[list[_Pending]]:
        """The episodes' logged rows and properties, `_GROUP` episodes at a time."""
        condition, seen = self.condition, set()
        group: list[_Pending] = []
        for ep in episodes:
            sid = int(ep.state.state_id)
            if sid in seen:
                raise ValueError(f"{condition}: state {sid} appears twice among the episodes")
            physics, sensordata, _ = _as_trajectory(
                self.layout, ep.physics, ep.sensordata, self.ctrl
            )
            group.append(
                _Pending(
                    recording_id=episode_recording_id(condition, sid),
                    name=episode_recording_name(condition, sid),
                    fields=_episode_fields(ep, condition, self.ctrl, self.log_every),
                    rows=physics[self.steps],
                    sensors=sensordata[self.steps],
                )
            )
            seen.add(sid)
            if len(group) == _GROUP:
                yield group
                group = []
        if not seen:
            raise ValueError(f"{condition}: no episodes to record")
        if group:
            yield group


def write_condition_recordings(
    path: str | os.PathLike[str],
    *,
    model: mujoco.MjModel,
    condition: str,
    episodes: Iterable[EpisodeRecord],
    ctrl: np.ndarray,
    stamp: Mapping[str, Any],
    log_every: int,
    application_id: str = APPLICATION_ID,
) -> int:
    """Atomically write the folder `path`: one .rrd per episode of a condition, and a blueprint.

    Each episode's recording goes to `episode_file_name` (its recording id, e.g.
    ``fast-state-000017.rrd``) and carries the properties `episode` and `provenance`, the
    model geometry and the episode's series (`log_episode`); the folder's
    ``blueprint.rbl`` is `default_blueprint`, so ``rerun <folder>/*`` opens them all in its
    layout. Episodes are consumed one at a time, so `episodes` may be a generator over rollout
    batches (see `_EpisodeStores`); a writer thread writes and fsyncs the recordings (at most
    `_QUEUE` wait) while the caller runs the next rollouts.

    Why a file per episode (not one file per condition): rerun 0.41 can put many recordings in
    one file only by streaming them through ``rerun rrd route``, which merges their indexes
    after the last one, single-threaded (0.6 ms a recording, half the cost of logging), and
    holds them in memory (~0.3 MB a recording). A file per episode costs one `write_rrd` call,
    scales to any number of episodes, and opens or travels on its own.

    Returns:
      the number of recordings written (no episodes is an error).
    """
    builder = _EpisodeStores(
        model=model, condition=condition, ctrl=ctrl, stamp=stamp, log_every=log_every
    )
    count = 0
    with atomic_directory(Path(path)) as folder:
        _save_blueprint(builder.blueprint, application_id, str(folder / RECORDING_FOLDER_BLUEPRINT))

        # fsync in a thread of its own: the disk's writeback then overlaps the rollouts (an fsync
        # after each write, or of every file at the end, cost the rollout stage more)
        syncer = _Worker(fsync_file, maxsize=0, name="mjtrial-rrd-syncer")

        def write(group: list[_Pending]) -> None:
            """Build and write a group's recordings, while the caller runs the next rollouts."""
            for recording_id, store in builder.build(group):
                target = folder / _file_name(recording_id)
                with _strict():
                    store.write_rrd(
                        target,
                        application_id=application_id,
                        recording_id=recording_id,
                    )
                syncer.put(target)

        worker = _Worker(write, maxsize=max(1, _QUEUE // _GROUP), name="mjtrial-rrd-writer")
        try:
            for group in builder.groups(episodes):
                worker.put(group)
                count += len(group)
            worker.finish()
        except BaseException:
            worker.cancel()
            syncer.cancel()
            raise
        syncer.put(folder / RECORDING_FOLDER_BLUEPRINT)
        syncer.finish()
    return count


def write_episode_recording(
    path: str | os.PathLike[str],
    *,
    model: mujoco.MjModel,
    condition: str,
    episode: EpisodeRecord,
    ctrl: np.ndarray,
    stamp: Mapping[str, Any],
    log_every: int,
    application_id: str = APPLICATION_ID,
) -> None:
    """Atomically write one episode's recording, and `default_blueprint`, to the file `path`.

    The recording is the one `write_condition_recordings` makes; the blueprint travels in the
    same file (through ``rerun rrd route``), so ``rerun <path>`` opens it in its layout.
    """
    builder = _EpisodeStores(
        model=model, condition=condition, ctrl=ctrl, stamp=stamp, log_every=log_every
    )
    path = Path(path)
    [group] = builder.groups([episode])
    [(recording_id, store)] = builder.build(group)
    with atomic_path(path) as tmp, _rrd_output(tmp, application_id, builder.blueprint) as out:
        _write_store(out, store, application_id=application_id, recording_id=recording_id)


def _episode_fields(
    ep: EpisodeRecord, condition: str, ctrl: np.ndarray, log_every: int
) -> dict[str, Any]:
    s = ep.state
    fields: dict[str, Any] = {
        "condition": str(condition),
        "state_id": int(s.state_id),
        "dx": float(s.dx),
        "dy": float(s.dy),
        "yaw": float(s.yaw),
        "mass": float(s.mass),
        "success": bool(ep.success),
        "final_height": float(ep.final_height),
        "failure_category": None if ep.failure_category is None else str(ep.failure_category),
        "log_every": int(log_every),
        "n_steps": int(ctrl.shape[0]),
    }
    return fields


def write_failures_rrd(
    path: str | os.PathLike[str],
    sources: Sequence[str | os.PathLike[str]],
    *,
    stamp: Mapping[str, Any],
    only_failures: bool = False,
    application_id: str = APPLICATION_ID,
) -> int:
    """Atomically gather the failed episodes (property success False) of .rrd files or folders.

    With `only_failures`, every recording of `sources` must be a failed episode (the caller
    chose them from the rollout tables): one that is not is an error, raised before writing.

    The file starts with a summary recording (id ``failures``: the count, the source file names
    and a table of the failures), so it carries its stamp even when nothing failed. Each failed
    recording is copied chunk for chunk under the id ``failures-<original id>`` (so both files
    can be open in one viewer); its `provenance` becomes `stamp`, the original stamp is kept as
    `source_provenance`. Memory holds one recording at a time.

    Returns:
      the number of failed episodes written.
    """
    path = Path(path)
    stamp_text = _stamp_json(stamp)
    readers: dict[Path, RrdReader] = {}
    failures: list[tuple[Path, StoreEntry, dict[str, Any]]] = []
    files = [f for source in sources for f in recording_files(source)]
    for source in files:
        reader = _open(source)
        for entry in reader.recordings():
            props = _properties(reader, entry)
            if props.get("success") is False:
                failures.append((source, entry, props))
                readers[source] = reader  # only files with failures stay open
            elif only_failures:
                raise ValueError(
                    f"{source}: recording {entry.recording_id!r} is not a failed episode "
                    f"(success {props.get('success')!r})"
                )
    ids = [entry.recording_id for _, entry, _ in failures]
    duplicates = sorted({i for i in ids if ids.count(i) > 1})
    if duplicates:
        raise ValueError(f"the same episode appears in several sources: {duplicates[:5]}")

    signals: Sequence[tuple[str, Sequence[str]]] = GANTRY_SIGNALS
    for source in files[:1]:  # the sources' signals, all recorded alike
        reader = readers.get(source) or _open(source)
        if recordings := reader.recordings():
            signals = list(_recorded_signals(reader, recordings[0]).items()) or signals
    blueprint = default_blueprint(signals)
    with atomic_path(path) as tmp, _rrd_output(tmp, application_id, blueprint) as out:
        names = [Path(s).name for s in sources]  # names only: no private paths in outputs
        summary = [
            _name_chunk(f"failures: {len(failures)} episode(s) from {len(names)} file(s)"),
            _property_chunk(PROVENANCE_PROPERTY, {_JSON_FIELD: stamp_text}),
            _property_chunk(
                FAILURES_PROPERTY, {"n_failures": len(failures), "sources": json.dumps(names)}
            ),
            _static_chunk(FAILURES_SUMMARY, [_failures_table(failures)]),
        ]
        _write_recording(out, summary, application_id=application_id, recording_id=FAILURES_SUMMARY)
        replaced = [
            f"{_PROPERTIES}/{PROVENANCE_PROPERTY}",
            f"{_PROPERTIES}/{SOURCE_PROVENANCE_PROPERTY}",
        ]
        for source, entry, props in failures:
            chunks = list(readers[source].store(store=entry).stream().drop(content=replaced))
            chunks.append(_property_chunk(PROVENANCE_PROPERTY, {_JSON_FIELD: stamp_text}))
            original = props.get(PROVENANCE_PROPERTY)
            if original is not None:
                fields = {_JSON_FIELD: json.dumps(original, allow_nan=False)}
                chunks.append(_property_chunk(SOURCE_PROVENANCE_PROPERTY, fields))
            rid = _FAILURE_PREFIX + entry.recording_id
            _write_recording(out, chunks, application_id=application_id, recording_id=rid)
    return len(failures)


def _failures_table(failures: Sequence[tuple[Path, Any, Mapping[str, Any]]]) -> rr.TextDocument:
    lines = [
        "| source | condition | state | failure | final height (m) |",
        "|---|---|---|---|---|",
    ]
    for source, _, p in failures:
        lines.append(
            f"| {source.name} | {p.get('condition')} | {p.get('state_id')} "
            f"| {p.get('failure_category') or '-'} | {p.get('final_height', float('nan')):.4f} |"
        )
    if not failures:
        lines.append("| - | - | - | - | - |")
    return rr.TextDocument("\n".join(lines), media_type=rr.MediaType.MARKDOWN)


# --------------------------------------------------------------------------------------------
# Reading, with rerun's own reader
# --------------------------------------------------------------------------------------------


def recording_files(path: str | os.PathLike[str]) -> list[Path]:
    """The .rrd files of `path`: itself, or the .rrd files of a folder, in name order."""
    path = Path(path)
    if path.is_dir():
        return sorted(p for p in path.glob("*.rrd") if p.is_file())
    if not path.is_file():
        raise FileNotFoundError(f"{path}: no such .rrd file or folder of .rrd files")
    return [path]


def _open(path: str | os.PathLike[str]) -> RrdReader:
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"{path}: no such .rrd file")
    try:
        return RrdReader(path)
    except (RuntimeError, ValueError, OSError) as exc:
        raise ValueError(f"{path}: not a readable .rrd file: {exc}") from exc


def _data_columns(batch: pa.RecordBatch) -> Iterator[tuple[str, pa.Array]]:
    for field, column in zip(batch.schema, batch.columns, strict=True):
        if (field.metadata or {}).get(b"rerun:kind") == b"data":
            yield field.name, column


def _raw_properties(reader: RrdReader, entry: StoreEntry) -> dict[str | None, dict[str, Any]]:
    """{property name (None: the recording's own info): {field: value}} of one recording."""
    stream = reader.store(store=entry).stream().filter(content=f"{_PROPERTIES}/**", is_static=True)
    out: dict[str | None, dict[str, Any]] = {}
    for chunk in stream:
        entity = chunk.entity_path
        prop = None if entity == _PROPERTIES else entity[len(_PROPERTIES) + 1 :]
        fields = out.setdefault(prop, {})
        for name, column in _data_columns(chunk.to_record_batch()):
            if len(column) == 0:
                continue
            values = column[len(column) - 1].as_py()  # static: the last row wins
            if values is not None:
                fields[name] = values[0] if len(values) == 1 else values
    return out


def _parse_json_property(fields: Mapping[str, Any] | None, what: str) -> dict[str, Any] | None:
    if not fields or _JSON_FIELD not in fields:
        return None
    try:
        value = json.loads(fields[_JSON_FIELD])
    except ValueError as exc:
        raise ValueError(f"corrupt {what} property: {exc}") from exc
    if not isinstance(value, dict):
        raise ValueError(f"corrupt {what} property: not a JSON object")
    return value


def _properties(reader: RrdReader, entry: StoreEntry) -> dict[str, Any]:
    raw = _raw_properties(reader, entry)
    info = raw.pop(None, {})
    out: dict[str, Any] = {
        "recording_id": entry.recording_id,
        "application_id": entry.application_id,
        "name": info.get(_NAME_COMPONENT),
    }
    if EPISODE_PROPERTY in raw:
        out.update(_episode_property(raw.pop(EPISODE_PROPERTY)))
    if FAILURES_PROPERTY in raw:
        fields = dict(raw.pop(FAILURES_PROPERTY))
        if isinstance(fields.get("sources"), str):
            fields["sources"] = json.loads(fields["sources"])
        out.update(fields)
    for prop in (PROVENANCE_PROPERTY, SOURCE_PROVENANCE_PROPERTY):
        if prop in raw:
            out[prop] = _parse_json_property(raw.pop(prop), f"{entry.recording_id}: {prop}")
    for prop, fields in raw.items():  # anything else, under its own name
        out[str(prop)] = fields
    return out


def list_recordings(path: str | os.PathLike[str]) -> list[dict[str, Any]]:
    """Properties of each recording in the file (or the folder's files), in file order.

    Each dict has recording_id, application_id, name and provenance (the stamp, parsed).
    Episode recordings add condition, state_id, dx, dy, yaw, mass, success, final_height,
    failure_category (None if absent), log_every, n_steps; copies in failures.rrd add
    source_provenance; failures.rrd's summary adds n_failures and sources.
    """
    out = []
    for file in recording_files(path):
        reader = _open(file)
        out.extend(_properties(reader, entry) for entry in reader.recordings())
    return out


def read_rrd_stamp(path: str | os.PathLike[str]) -> dict[str, Any] | None:
    """The file's provenance stamp: the `provenance` property of its first recording.

    For a folder of recordings, its first file's (they all hold the folder's stamp). None when
    there is no recording or the first recording has no stamp.
    """
    files = recording_files(path)
    if not files:
        return None
    reader = _open(files[0])
    entries = reader.recordings()
    if not entries:
        return None
    raw = _raw_properties(reader, entries[0])
    return _parse_json_property(raw.get(PROVENANCE_PROPERTY), f"{path}: provenance")


def _find_episode(reader: RrdReader, path: Path, condition: str, state_id: int) -> StoreEntry:
    rid = episode_recording_id(condition, state_id)
    wanted = (rid, _FAILURE_PREFIX + rid)
    entries = reader.recordings()
    for entry in entries:
        if entry.recording_id in wanted:
            return entry
    raise KeyError(
        f"{path}: no recording of condition {condition!r}, state {state_id} "
        f"(recording id {rid!r}) among its {len(entries)} recording(s)"
    )


def _column_values(column: pa.Array, instances: int, what: str) -> np.ndarray:
    """A list<...> column with `instances` values per row, as an (n, instances * k) array."""
    lengths = pc.list_value_length(column).to_numpy(zero_copy_only=False)
    if not np.all(lengths == instances):
        raise ValueError(f"{what}: expected {instances} instance(s) per row")
    values = column.flatten()
    if pa.types.is_fixed_size_list(values.type):
        values = values.flatten()
    return values.to_numpy(zero_copy_only=False).astype(np.float64).reshape(len(column), -1)


_SERIES_NAMES = "SeriesLines:names"


def _recorded_signals(reader: RrdReader, entry: StoreEntry) -> dict[str, list[str]]:
    """{entity (no leading slash): series names} of a recording, from its static SeriesLines."""
    out: dict[str, list[str]] = {}
    stream = reader.store(store=entry).stream().filter(is_static=True, components=_SERIES_NAMES)
    for chunk in stream:
        batch = chunk.to_record_batch()
        column = batch.column(batch.schema.names.index(_SERIES_NAMES))
        names = column[len(column) - 1].as_py()  # static: the last row wins
        if names:
            out[chunk.entity_path.lstrip("/")] = names
    return out


def read_episode(
    path: str | os.PathLike[str], *, condition: str, state_id: int
) -> dict[str, np.ndarray]:
    """One episode's logged series, in time order.

    Returns arrays over the n logged steps: time (n,) simulated seconds (rerun keeps integer
    nanoseconds, so this is physics time rounded to 1 ns); step (n,) the physics step index;
    cube_position (n, 3) and cube_quat_wxyz (n, 4) (float32 precision: rerun stores transforms
    as float32); finger_opening (n,), cube_height (n,), ctrl (n, 4) and contact_force (n, 2)
    (left, right normal force) exactly as logged (float64).

    `path` is a .rrd file or a condition's folder of recordings (`write_condition_recordings`).

    Raises:
      KeyError: the file has no recording of that condition and state.
    """
    path = Path(path)
    if path.is_dir():
        path = path / episode_file_name(condition, state_id)
        if not path.is_file():
            raise KeyError(
                f"{path.parent}: no recording of condition {condition!r}, state {state_id} "
                f"(no file {path.name})"
            )
    reader = _open(path)
    entry = _find_episode(reader, path, condition, state_id)
    cube = f"{WORLD}/{_part(CUBE_BODY)}"  # a free joint's body is a child of the world body
    signals = _recorded_signals(reader, entry)
    where = {name: (e, i) for e, names in signals.items() for i, name in enumerate(names)}
    missing = [name for name in SIGNALS if name not in where]
    if missing:
        raise ValueError(f"{path}: recording {entry.recording_id!r} has no series {missing}")
    wanted: dict[str, list[tuple[str, int]]] = {
        e: [(_SCALARS, len(names))] for e, names in signals.items() if set(names) & set(SIGNALS)
    }
    wanted.setdefault(cube, []).extend([(_TRANSLATION, 1), (_QUATERNION, 1)])
    parts: dict[str, list[dict[str, np.ndarray]]] = {e: [] for e in wanted}
    store = reader.store(store=entry)
    stream = store.stream().filter(content=[f"/{e}" for e in wanted], has_timeline=TIMELINE)
    for chunk in stream:
        entity = chunk.entity_path.lstrip("/")
        batch = chunk.to_record_batch()
        names = batch.schema.names
        part = {"time_ns": batch.column(names.index(TIMELINE)).cast(pa.int64()).to_numpy()}
        for component, width in wanted[entity]:
            if component in names:
                column = batch.column(names.index(component))
                part[component] = _column_values(column, width, f"{entity} {component}")
        parts[entity].append(part)

    series: dict[str, dict[str, np.ndarray]] = {}
    for entity, chunks in parts.items():
        keys = {k for c in chunks for k in c}
        missing = [c for c, _ in wanted[entity] if c not in keys]
        if not chunks or missing or any(set(c) != keys for c in chunks):
            raise ValueError(
                f"{path}: recording {entry.recording_id!r}: incomplete data at {entity}"
            )
        merged = {k: np.concatenate([c[k] for c in chunks]) for k in keys}
        order = np.argsort(merged["time_ns"], kind="stable")  # ties keep the logged order
        series[entity] = {k: v[order] for k, v in merged.items()}
    time_ns = series[cube]["time_ns"]
    for entity, s in series.items():
        if not np.array_equal(s["time_ns"], time_ns):
            raise ValueError(f"{path}: {entity} is not logged at the same times as {cube}")

    props = _episode_property(_raw_properties(reader, entry).get(EPISODE_PROPERTY, {}))
    if "n_steps" not in props or "log_every" not in props:
        raise ValueError(f"{path}: recording {entry.recording_id!r} lacks n_steps / log_every")
    steps = logged_steps(int(props["n_steps"]), int(props["log_every"]))
    if len(steps) != len(time_ns):
        raise ValueError(
            f"{path}: {len(time_ns)} rows, but n_steps and log_every give {len(steps)}"
        )

    def signal(name: str) -> np.ndarray:
        entity, column = where[name]
        return series[entity][_SCALARS][:, column]

    return {
        "time": time_ns / 1e9,
        "step": steps,
        "cube_position": series[cube][_TRANSLATION],
        "cube_quat_wxyz": rerun_to_mujoco_quat(series[cube][_QUATERNION]),
        "finger_opening": signal("finger_opening"),
        "ctrl": np.column_stack([signal(name) for name in CTRL_SERIES]),
        "cube_height": signal("cube_height"),
        "contact_force": np.column_stack([signal(name) for name in CONTACT_SERIES]),
    }
