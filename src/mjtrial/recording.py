"""Rerun recordings of episodes: the one module that talks to rerun.

Why rerun: an episode's outcome is a handful of numbers, but *why* a grasp failed is only visible
in its motion. Every condition gets one ``.rrd`` file holding one rerun recording per episode,
and the failed episodes of all conditions are gathered into ``failures.rrd``.

Layout of a recording (entity paths are built only here, by the constants and functions below):

* ``world``: view coordinates (z up).
* ``world/<body>``: the body's world pose per logged step (``Transform3D``). Bodies are siblings:
  each carries its *world* pose, not its pose relative to its MuJoCo parent.
* ``world/<body>/<geom>``: the geom's shape and colour, and its pose in the body (static).
* ``plots/cube_height``, ``plots/finger_opening``: one series each; ``plots/ctrl`` (x, y, z,
  gripper) and ``plots/contact_force`` (left, right normal force): one entity holding several
  named series, because every entity costs ~7 kB per episode in row ids and timestamps.
* recording properties ``episode`` (condition, state, outcome, ``log_every``, ``n_steps``) and
  ``provenance`` (the stamp as JSON, see :mod:`mjtrial.provenance`).

Time series use one timeline, ``sim_time``: simulated seconds, stored by rerun as integer
nanoseconds.

Writing many recordings into one file: each recording's chunks are built with
``rr.chunk.Chunk.from_columns`` (the twin of ``send_columns``) and encoded on their own with
``LazyChunkStream.write_rrd``; the encoded recordings are piped one after another into
``rerun rrd route`` (the CLI in the rerun-sdk wheel), which writes them as one stream with one
valid footer. Plain concatenation is not enough: rerun 0.41's reader and ``rerun rrd verify``
reject concatenated files. (A ``RecordingStream`` per recording works too but costs ~3 ms more
per episode, and a blueprint sent into a recording's stream can make ``route`` panic, so the
blueprint travels as a stream of its own.) This process holds one episode at a time; ``route``
keeps ~0.3 MB of index per recording until it writes the footer. The CLI runs with ``CI`` set,
the only environment switch of rerun 0.41 that stops it from writing analytics files under the
home folder. (rerun 0.41's ``route`` panics when given its own output as input: combine these
files with ``rerun rrd merge`` instead.)
"""

from __future__ import annotations

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
from collections.abc import Iterable, Iterator, Mapping, Sequence
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
from rerun.chunk import Chunk, LazyChunkStream, RrdReader, StoreEntry
from rerun.error_utils import catch_and_log_exceptions

from mjtrial.atomic import atomic_path
from mjtrial.protocol import CTRL_GRIPPER, CTRL_X, CTRL_Y, CTRL_Z
from mjtrial.simulate import CUBE_BODY, FULLPHYSICS, STATE_QPOS, STATE_TIME, InitialState

__all__ = [
    "APPLICATION_ID",
    "TIMELINE",
    "EpisodeRecord",
    "body_entity",
    "body_poses",
    "default_blueprint",
    "episode_recording_id",
    "episode_recording_name",
    "geom_entity",
    "list_recordings",
    "log_episode",
    "log_model_geometry",
    "logged_steps",
    "mujoco_to_rerun_quat",
    "read_episode",
    "read_rrd_stamp",
    "rerun_to_mujoco_quat",
    "write_condition_recordings",
    "write_failures_rrd",
]

# --------------------------------------------------------------------------------------------
# Names: every entity path, timeline and property name lives here
# --------------------------------------------------------------------------------------------

APPLICATION_ID = "mjtrial"
TIMELINE = "sim_time"
WORLD = "world"
CUBE_HEIGHT = "plots/cube_height"
FINGER_OPENING = "plots/finger_opening"
CTRL = "plots/ctrl"
CTRL_SERIES = ("x", "y", "z", "gripper")
_CTRL_COLUMNS = (CTRL_X, CTRL_Y, CTRL_Z, CTRL_GRIPPER)
CONTACT_FORCE = "plots/contact_force"
CONTACT_SERIES = ("left", "right")
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
    """Entity path of a body: ``world/<body name or body_<i>>``."""
    return f"{WORLD}/{_part(_body_name(model, body_id))}"


def geom_entity(model: mujoco.MjModel, geom_id: int) -> str:
    """Entity path of a geom: ``world/<body>/<geom name or geom_<i>>``."""
    name = model.geom(geom_id).name or f"geom_{geom_id}"
    return f"{body_entity(model, int(model.geom_bodyid[geom_id]))}/{_part(name)}"


def episode_recording_id(condition: str, state_id: int) -> str:
    """Deterministic recording id, so reruns of the same episode are comparable."""
    return f"{condition}-state-{int(state_id):06d}"


def episode_recording_name(condition: str, state_id: int) -> str:
    """Recording name shown in the viewer."""
    return f"{condition} / state {int(state_id)}"


def default_blueprint() -> rrb.Blueprint:
    """Viewer layout: the scene on the left, cube height and contact forces on the right."""
    return rrb.Blueprint(
        rrb.Horizontal(
            rrb.Spatial3DView(origin=WORLD),
            rrb.Vertical(
                rrb.TimeSeriesView(origin=CUBE_HEIGHT),
                rrb.TimeSeriesView(origin=CONTACT_FORCE),
            ),
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


def _geom_shape(model: mujoco.MjModel, g: int) -> Any | None:
    """The rerun archetype drawing geom g in its own frame, or None for unsupported types."""
    gtype = mujoco.mjtGeom(int(model.geom_type[g]))
    size = model.geom_size[g]
    color = [_geom_rgba(model, g)]
    solid = rr.components.FillMode.Solid
    if gtype == mujoco.mjtGeom.mjGEOM_BOX:
        return rr.Boxes3D(half_sizes=[size], colors=color, fill_mode=solid)
    if gtype == mujoco.mjtGeom.mjGEOM_SPHERE:
        return rr.Ellipsoids3D(half_sizes=[[size[0]] * 3], colors=color, fill_mode=solid)
    if gtype == mujoco.mjtGeom.mjGEOM_ELLIPSOID:
        return rr.Ellipsoids3D(half_sizes=[size], colors=color, fill_mode=solid)
    if gtype == mujoco.mjtGeom.mjGEOM_CAPSULE:
        # MuJoCo: centred on the origin along local z, half-length size[1];
        # rerun: from the origin along +z.
        return rr.Capsules3D(
            lengths=[2 * size[1]],
            radii=[size[0]],
            translations=[[0.0, 0.0, -size[1]]],
            colors=color,
            fill_mode=solid,
        )
    if gtype == mujoco.mjtGeom.mjGEOM_CYLINDER:
        return rr.Cylinders3D(lengths=[2 * size[1]], radii=[size[0]], colors=color, fill_mode=solid)
    if gtype == mujoco.mjtGeom.mjGEOM_PLANE:
        half = [s if s > 0 else INFINITE_PLANE_HALF_SIZE for s in size[:2]]
        return rr.Boxes3D(
            half_sizes=[[half[0], half[1], PLANE_THICKNESS / 2]],
            centers=[[0.0, 0.0, -PLANE_THICKNESS / 2]],
            colors=color,
            fill_mode=solid,
        )
    if gtype == mujoco.mjtGeom.mjGEOM_MESH:
        mesh = int(model.geom_dataid[g])
        v0, nv = int(model.mesh_vertadr[mesh]), int(model.mesh_vertnum[mesh])
        f0, nf = int(model.mesh_faceadr[mesh]), int(model.mesh_facenum[mesh])
        return rr.Mesh3D(
            vertex_positions=model.mesh_vert[v0 : v0 + nv],
            triangle_indices=model.mesh_face[f0 : f0 + nf],
            albedo_factor=color[0],
        )
    return None


def _geometry_items(model: mujoco.MjModel) -> list[tuple[str, tuple[Any, ...]]]:
    """(entity, archetypes) to log statically: view coordinates and every visible geom."""
    items: list[tuple[str, tuple[Any, ...]]] = [
        (WORLD, (rr.ViewCoordinates(xyz=rr.ViewCoordinates.RIGHT_HAND_Z_UP),))
    ]
    with _strict():
        for g in range(model.ngeom):
            if int(model.geom_group[g]) not in VISIBLE_GEOM_GROUPS:
                continue
            shape = _geom_shape(model, g)
            if shape is None:
                gtype = mujoco.mjtGeom(int(model.geom_type[g])).name
                warnings.warn(f"geom {g} ({gtype}): no rerun equivalent, not drawn", stacklevel=3)
                continue
            pose = rr.Transform3D(
                translation=model.geom_pos[g],
                quaternion=rr.Quaternion(xyzw=mujoco_to_rerun_quat(model.geom_quat[g])),
            )
            items.append((geom_entity(model, g), (pose, shape)))
    return items


def _plot_style_items() -> list[tuple[str, tuple[Any, ...]]]:
    """(entity, archetypes) naming the series of the multi-series plots."""
    return [
        (CTRL, (rr.SeriesLines(names=list(CTRL_SERIES)),)),
        (CONTACT_FORCE, (rr.SeriesLines(names=list(CONTACT_SERIES)),)),
    ]


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
class _Layout:
    """Where the logged quantities sit in the model's state and sensor vectors."""

    nstate: int
    nsensordata: int
    nu: int
    bodies: tuple[tuple[int, str], ...]  # (body id, entity path); the world body never moves
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
        normals = []
        for s in CONTACT_SENSORS:
            sid = named(mujoco.mjtObj.mjOBJ_SENSOR, s)
            if model.sensor_dim[sid] != 4:
                raise ValueError(
                    f"sensor {s!r}: expected 4 values (found, force), got {model.sensor_dim[sid]}"
                )
            normals.append(int(model.sensor_adr[sid]) + 1 + CONTACT_NORMAL_AXIS)
        return cls(
            nstate=mujoco.mj_stateSize(model, FULLPHYSICS),
            nsensordata=model.nsensordata,
            nu=model.nu,
            bodies=tuple((b, body_entity(model, b)) for b in range(1, model.nbody)),
            cube_z=STATE_QPOS + cube_adr + 2,
            fingers=fingers,
            contact_normals=tuple(normals),
        )


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


def _multi_series(values: np.ndarray) -> Any:
    """Scalars columns with one row per time and several series per row."""
    n, width = values.shape
    return rr.Scalars.columns(scalars=np.ascontiguousarray(values).ravel()).partition(
        np.full(n, width)
    )


def _episode_columns(
    model: mujoco.MjModel,
    layout: _Layout,
    *,
    physics: Any,
    sensordata: Any,
    ctrl: Any,
    log_every: int,
) -> list[tuple[str, list[rr.TimeColumn], Any]]:
    """(entity, indexes, columns) of an episode's time series, ready for send_columns."""
    physics, sensordata, ctrl = _as_trajectory(layout, physics, sensordata, ctrl)
    steps = logged_steps(ctrl.shape[0], log_every)
    rows = physics[steps]
    # rerun's own float path truncates (0.006 s -> 5999999 ns); round to the nanosecond here.
    time_ns = np.rint(rows[:, STATE_TIME] * 1e9).astype(np.int64)
    indexes = [rr.TimeColumn(TIMELINE, duration=time_ns.astype("timedelta64[ns]"))]
    n = len(steps)
    out: list[tuple[str, list[rr.TimeColumn], Any]] = []
    positions, orientations = _body_frames(model, rows[:, STATE_QPOS : STATE_QPOS + model.nq])
    for body, entity in layout.bodies:
        translation = np.broadcast_to(positions[body], (n, 3))
        quat = orientations[body]
        if quat.ndim == 1 and np.allclose(quat, (1.0, 0.0, 0.0, 0.0), rtol=0.0, atol=1e-12):
            # never rotates (the gantry): translation only; no rotation is the default
            columns = rr.Transform3D.columns(translation=translation)
        else:
            xyzw = mujoco_to_rerun_quat(np.broadcast_to(quat, (n, 4)))
            columns = rr.Transform3D.columns(translation=translation, quaternion=xyzw)
        out.append((entity, indexes, columns))
    fingers = rows[:, list(layout.fingers)].mean(axis=1)
    normals = np.abs(sensordata[steps][:, list(layout.contact_normals)])
    out += [
        (CUBE_HEIGHT, indexes, rr.Scalars.columns(scalars=rows[:, layout.cube_z].copy())),
        (FINGER_OPENING, indexes, rr.Scalars.columns(scalars=fingers)),
        (CTRL, indexes, _multi_series(ctrl[steps][:, list(_CTRL_COLUMNS)])),
        (CONTACT_FORCE, indexes, _multi_series(normals)),
    ]
    return out


def log_model_geometry(rec: rr.RecordingStream, model: mujoco.MjModel) -> None:
    """Log every visible geom (groups 0-2) statically, under its body.

    Each geom entity carries its shape, MuJoCo colour (the material's unless the geom sets its
    own rgba) and its pose in the body; the body entity above it gets the per-step pose
    (`log_episode`), so the scene moves as MuJoCo's does. Planes are drawn as flat boxes.
    """
    with _strict():
        for entity, archetypes in _geometry_items(model):
            rec.log(entity, *archetypes, static=True, strict=True)


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

    Body poses come from qpos (`body_poses`); each entity's series goes out in one
    `send_columns` call on the `sim_time` timeline (= physics[t, 0]).

    Args:
      rec: the episode's recording.
      model: the model the episode ran on.
      physics: (n_steps, nstate) mjSTATE_FULLPHYSICS after each step.
      sensordata: (n_steps, nsensordata) sensors after each step.
      ctrl: (n_steps, nu) the ctrl applied at each step.
      log_every: log every `log_every`-th step (>= 1); the last step is always logged.
    """
    layout = _Layout.of(model)
    series = _episode_columns(
        model, layout, physics=physics, sensordata=sensordata, ctrl=ctrl, log_every=log_every
    )
    with _strict():
        for entity, archetypes in _plot_style_items():
            rec.log(entity, *archetypes, static=True, strict=True)
        for entity, indexes, columns in series:
            rec.send_columns(entity, indexes=indexes, columns=columns, strict=True)


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
    columns = []
    with _strict():
        for archetype in archetypes:
            for batch in archetype.as_component_batches():
                columns.append(batch.partition([len(batch.as_arrow_array())]))
        return Chunk.from_columns(entity, [], columns)


def _property_chunk(name: str, fields: Mapping[str, Any]) -> Chunk:
    # One-element lists: rerun converts bare Python scalars ~10x slower (exception paths).
    values = {k: v if isinstance(v, list) else [v] for k, v in fields.items()}
    with _strict():
        return Chunk.from_property(name, rr.AnyValues(**values))


def _name_chunk(name: str) -> Chunk:
    return _static_chunk(_PROPERTIES, [rr.archetypes.RecordingInfo(name=name)])


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


class _RrdFileWriter:
    """Writes encoded rerun streams, one after another, as one valid .rrd file.

    Feeds them to ``rerun rrd route -o <path>``, which re-frames them as a single stream with one
    footer, without decoding the payloads. A feeder thread does the writing, so the caller
    builds the next recording while route works on the last ones; the queue holds at most
    `_QUEUE` encoded recordings, which bounds memory.
    """

    _QUEUE = 4

    def __init__(self, path: Path) -> None:
        self._stderr: IO[bytes] = tempfile.TemporaryFile()
        self._proc = subprocess.Popen(
            [_rerun_cli(), "rrd", "route", "-o", str(path)],
            stdin=subprocess.PIPE,
            stdout=subprocess.DEVNULL,
            stderr=self._stderr,
            env=_cli_env(),
        )
        self._queue: queue.Queue[bytes | None] = queue.Queue(maxsize=self._QUEUE)
        self._failed = False
        self._feeder = threading.Thread(target=self._feed, name="mjtrial-rrd-route", daemon=True)
        self._feeder.start()

    def _feed(self) -> None:
        assert self._proc.stdin is not None
        while (encoded := self._queue.get()) is not None:
            if self._failed:
                continue  # keep draining, so the producer never blocks on a full queue
            try:
                self._proc.stdin.write(encoded)
            except OSError:  # route exited early (BrokenPipeError) or the pipe broke
                self._failed = True
        try:
            self._proc.stdin.close()
        except OSError:
            self._failed = True

    def write(self, encoded: bytes) -> None:
        if self._failed:
            self._proc.wait()
            raise RuntimeError(f"rerun rrd route stopped early: {self._error_text()}")
        self._queue.put(encoded)

    def close(self) -> None:
        self._queue.put(None)
        self._feeder.join()
        code = self._proc.wait()
        try:
            if code != 0 or self._failed:
                raise RuntimeError(f"rerun rrd route failed (exit {code}): {self._error_text()}")
        finally:
            self._stderr.close()

    def abort(self) -> None:
        self._failed = True
        self._proc.kill()
        self._proc.wait()
        self._queue.put(None)  # the feeder drains what is left and exits
        self._feeder.join()
        self._stderr.close()

    def _error_text(self) -> str:
        self._stderr.seek(0)
        text = self._stderr.read().decode("utf-8", "replace").strip()
        return text[-2000:] or "no output"


@contextmanager
def _rrd_output(path: Path) -> Iterator[tuple[_RrdFileWriter, Path]]:
    """(writer of the final stream, scratch directory next to `path`)."""
    with tempfile.TemporaryDirectory(dir=path.parent, prefix=f".{path.name}.parts-") as scratch:
        writer = _RrdFileWriter(path)
        try:
            yield writer, Path(scratch)
        except BaseException:
            writer.abort()
            raise
        writer.close()


def _encode(
    chunks: Iterable[Chunk], *, application_id: str, recording_id: str, scratch: Path
) -> bytes:
    """One recording as an encoded rerun stream (what a .rrd file of it would hold)."""
    part = scratch / "recording.rrd"
    with _strict():
        LazyChunkStream.from_iter(chunks).write_rrd(
            part, application_id=application_id, recording_id=recording_id
        )
    try:
        return part.read_bytes()
    finally:
        part.unlink()


def _blueprint_bytes(application_id: str, scratch: Path) -> bytes:
    """`default_blueprint` as a stream of its own (an .rbl file), active and default."""
    part = scratch / "blueprint.rbl"
    try:
        default_blueprint().save(application_id, part)
    except RuntimeError as exc:  # e.g. "Blueprint stream has no store info"
        raise RuntimeError(
            f"rerun could not encode the blueprint ({exc}); is rerun disabled (RERUN=off)?"
        ) from exc
    try:
        return part.read_bytes()
    finally:
        part.unlink()


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
    """Atomically write one .rrd holding one recording per episode of a condition.

    Episodes are consumed one at a time, so `episodes` may be a generator over rollout batches
    and memory stays bounded by one episode. Recording ids are deterministic
    (`episode_recording_id`); each recording carries the properties `episode` and `provenance`,
    the model geometry and the episode's series (`log_episode`); the file carries
    `default_blueprint`.

    Returns:
      the number of recordings written (no episodes is an error).
    """
    path = Path(path)
    stamp_text = _stamp_json(stamp)
    layout = _Layout.of(model)
    ctrl = np.asarray(ctrl, dtype=np.float64)
    if ctrl.ndim != 2 or ctrl.shape[1] != layout.nu:
        raise ValueError(f"ctrl: expected shape (n_steps, {layout.nu}), got {ctrl.shape}")
    logged_steps(ctrl.shape[0], log_every)  # validate before any work
    static = [_static_chunk(e, a) for e, a in _geometry_items(model) + _plot_style_items()]
    seen: set[int] = set()
    with atomic_path(path) as tmp, _rrd_output(tmp) as (out, scratch):
        out.write(_blueprint_bytes(application_id, scratch))
        for ep in episodes:
            sid = int(ep.state.state_id)
            if sid in seen:
                raise ValueError(f"{condition}: state {sid} appears twice among the episodes")
            series = _episode_columns(
                model,
                layout,
                physics=ep.physics,
                sensordata=ep.sensordata,
                ctrl=ctrl,
                log_every=log_every,
            )
            with _strict():
                chunks = [
                    _name_chunk(episode_recording_name(condition, sid)),
                    _property_chunk(
                        EPISODE_PROPERTY, _episode_fields(ep, condition, ctrl, log_every)
                    ),
                    _property_chunk(PROVENANCE_PROPERTY, {_JSON_FIELD: stamp_text}),
                    # the same static chunks in every recording, each under a fresh chunk id
                    *(c.with_entity_path(c.entity_path) for c in static),
                    *(Chunk.from_columns(e, i, c) for e, i, c in series),
                ]
            rid = episode_recording_id(condition, sid)
            out.write(
                _encode(chunks, application_id=application_id, recording_id=rid, scratch=scratch)
            )
            seen.add(sid)
        if not seen:
            raise ValueError(f"{condition}: no episodes to record")
    return len(seen)


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
        "log_every": int(log_every),
        "n_steps": int(ctrl.shape[0]),
    }
    if ep.failure_category is not None:  # absent means None: rerun has no typed null
        fields["failure_category"] = str(ep.failure_category)
    return fields


def write_failures_rrd(
    path: str | os.PathLike[str],
    sources: Sequence[str | os.PathLike[str]],
    *,
    stamp: Mapping[str, Any],
    application_id: str = APPLICATION_ID,
) -> int:
    """Atomically gather the failed episodes (property success False) of condition .rrd files.

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
    for source in map(Path, sources):
        reader = readers.setdefault(source, _open(source))
        for entry in reader.recordings():
            props = _properties(reader, entry)
            if props.get("success") is False:
                failures.append((source, entry, props))
    ids = [entry.recording_id for _, entry, _ in failures]
    duplicates = sorted({i for i in ids if ids.count(i) > 1})
    if duplicates:
        raise ValueError(f"the same episode appears in several sources: {duplicates[:5]}")

    with atomic_path(path) as tmp, _rrd_output(tmp) as (out, scratch):
        out.write(_blueprint_bytes(application_id, scratch))
        names = [Path(s).name for s in sources]  # names only: no private paths in outputs
        summary = [
            _name_chunk(f"failures: {len(failures)} episode(s) from {len(names)} file(s)"),
            _property_chunk(PROVENANCE_PROPERTY, {_JSON_FIELD: stamp_text}),
            _property_chunk(
                FAILURES_PROPERTY, {"n_failures": len(failures), "sources": json.dumps(names)}
            ),
            _static_chunk(FAILURES_SUMMARY, [_failures_table(failures)]),
        ]
        out.write(
            _encode(
                summary,
                application_id=application_id,
                recording_id=FAILURES_SUMMARY,
                scratch=scratch,
            )
        )
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
            out.write(
                _encode(chunks, application_id=application_id, recording_id=rid, scratch=scratch)
            )
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
        out.update({"failure_category": None, **raw.pop(EPISODE_PROPERTY)})
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
    """Properties of each recording in the file, in file order.

    Each dict has recording_id, application_id, name and provenance (the stamp, parsed).
    Episode recordings add condition, state_id, dx, dy, yaw, mass, success, final_height,
    failure_category (None if absent), log_every, n_steps; copies in failures.rrd add
    source_provenance; failures.rrd's summary adds n_failures and sources.
    """
    reader = _open(path)
    return [_properties(reader, entry) for entry in reader.recordings()]


def read_rrd_stamp(path: str | os.PathLike[str]) -> dict[str, Any] | None:
    """The file's provenance stamp: the `provenance` property of its first recording.

    None when the file holds no recording or its first recording has no stamp.
    """
    reader = _open(path)
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


def read_episode(
    path: str | os.PathLike[str], *, condition: str, state_id: int
) -> dict[str, np.ndarray]:
    """One episode's logged series, in time order.

    Returns arrays over the n logged steps: time (n,) simulated seconds (rerun keeps integer
    nanoseconds, so this is physics time rounded to 1 ns); step (n,) the physics step index;
    cube_position (n, 3) and cube_quat_wxyz (n, 4) (float32 precision: rerun stores transforms
    as float32); finger_opening (n,), cube_height (n,), ctrl (n, 4) and contact_force (n, 2)
    (left, right normal force) exactly as logged (float64).

    Raises:
      KeyError: the file has no recording of that condition and state.
    """
    path = Path(path)
    reader = _open(path)
    entry = _find_episode(reader, path, condition, state_id)
    cube = f"{WORLD}/{_part(CUBE_BODY)}"
    wanted: dict[str, list[tuple[str, int]]] = {
        cube: [("Transform3D:translation", 1), ("Transform3D:quaternion", 1)],
        CUBE_HEIGHT: [("Scalars:scalars", 1)],
        FINGER_OPENING: [("Scalars:scalars", 1)],
        CTRL: [("Scalars:scalars", len(CTRL_SERIES))],
        CONTACT_FORCE: [("Scalars:scalars", len(CONTACT_SERIES))],
    }
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
    time_ns = series[CUBE_HEIGHT]["time_ns"]
    for entity, s in series.items():
        if not np.array_equal(s["time_ns"], time_ns):
            raise ValueError(f"{path}: {entity} is not logged at the same times as {CUBE_HEIGHT}")

    props = _raw_properties(reader, entry).get(EPISODE_PROPERTY, {})
    if "n_steps" not in props or "log_every" not in props:
        raise ValueError(f"{path}: recording {entry.recording_id!r} lacks n_steps / log_every")
    steps = logged_steps(int(props["n_steps"]), int(props["log_every"]))
    if len(steps) != len(time_ns):
        raise ValueError(
            f"{path}: {len(time_ns)} rows, but n_steps and log_every give {len(steps)}"
        )

    def scalars(entity: str) -> np.ndarray:
        return series[entity]["Scalars:scalars"]

    return {
        "time": time_ns / 1e9,
        "step": steps,
        "cube_position": series[cube]["Transform3D:translation"],
        "cube_quat_wxyz": rerun_to_mujoco_quat(series[cube]["Transform3D:quaternion"]),
        "finger_opening": scalars(FINGER_OPENING)[:, 0],
        "ctrl": scalars(CTRL),
        "cube_height": scalars(CUBE_HEIGHT)[:, 0],
        "contact_force": scalars(CONTACT_FORCE),
    }
