"""Rerun recordings of episodes: the one module that talks to rerun.

Why rerun: an episode's outcome is a handful of numbers, but *why* a grasp failed is only visible
in its motion. Every condition therefore gets one ``.rrd`` file holding one rerun recording per
episode, and the failed episodes of all conditions are gathered into ``failures.rrd``.

Layout of a recording (entity paths are built only here, by the constants and functions below):

* ``world/<body>``: the body's world pose per logged step (``Transform3D``); bodies are siblings
  because each carries its *world* pose, not the pose relative to its MuJoCo parent.
* ``world/<body>/<geom>``: the geom's shape, colour and pose in its body (static).
* ``plots/...``: scalar series (cube height, finger opening, ctrl, contact normal forces).
* recording properties ``episode`` (condition, state, outcome, ``log_every``) and ``provenance``
  (the stamp as JSON; see :mod:`mjtrial.provenance`).

Time-series data go out with ``send_columns`` on two timelines: ``sim_time`` (simulated seconds,
stored by rerun as integer nanoseconds) and ``step`` (the physics step index, which stays
unique even when a halted episode's time stops advancing).

Several recordings in one file: each recording is encoded into memory, and the encoded streams
are piped one after another into ``rerun rrd route`` (the CLI shipped in the rerun-sdk wheel),
which writes them as a single stream with one valid footer. Plain concatenation is not enough:
rerun 0.41 readers use the footer of the *last* stream and reject the file. Memory is bounded
by one encoded episode. The CLI runs with ``CI`` set, the only switch rerun 0.41 reads from the
environment that stops it from creating analytics files under the home folder.
"""

from __future__ import annotations

import importlib.util
import json
import os
import shutil
import subprocess
import sys
import tempfile
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
from rerun.error_utils import catch_and_log_exceptions

from mjtrial.atomic import atomic_path
from mjtrial.protocol import CTRL_GRIPPER, CTRL_X, CTRL_Y, CTRL_Z
from mjtrial.simulate import CUBE_BODY, FULLPHYSICS, STATE_QPOS, STATE_TIME, InitialState

__all__ = [
    "APPLICATION_ID",
    "EpisodeRecord",
    "TIMELINE",
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
STEP_TIMELINE = "step"
WORLD = "world"
PLOTS = "plots"
CUBE_HEIGHT = f"{PLOTS}/cube_height"
FINGER_OPENING = f"{PLOTS}/finger_opening"
CTRL = f"{PLOTS}/ctrl"
CTRL_NAMES = ("x", "y", "z", "gripper")  # ctrl column order: CTRL_X, CTRL_Y, CTRL_Z, CTRL_GRIPPER
CONTACT_FORCE = f"{PLOTS}/contact_force"
CONTACT_SIDES = ("left", "right")
FAILURES_SUMMARY = "failures"

EPISODE_PROPERTY = "episode"
PROVENANCE_PROPERTY = "provenance"
SOURCE_PROVENANCE_PROPERTY = "source_provenance"
FAILURES_PROPERTY = "failures"
_JSON_FIELD = "json"
_PROPERTIES = "/" + rr.RECORDING_PROPERTIES_PATH.strip("/")  # entity of recording properties

# Model names the plots read (see models/gantry_gripper/gantry_gripper.xml).
FINGER_JOINTS = ("left_finger", "right_finger")
CONTACT_SENSORS = ("left_pad_cube", "right_pad_cube")  # data="found force": [found, fx, fy, fz]
CONTACT_NORMAL_AXIS = 1  # the pads face each other along world y: normal force = |F_y|

# Geoms in these groups are logged: the ones MuJoCo's viewer shows by default (groups 0-2).
# Groups 3-5 are, by convention, collision duplicates and helpers hidden by default.
VISIBLE_GEOM_GROUPS = (0, 1, 2)
# Half-size (m) drawn for an infinite plane (MuJoCo plane size 0).
INFINITE_PLANE_HALF_SIZE = 5.0
_DEFAULT_GEOM_RGBA = (0.5, 0.5, 0.5, 1.0)

_RECORDING_ID_PREFIX_FAILURES = "failures-"


def _part(name: str) -> str:
    return rr.escape_entity_path_part(name)


def _body_name(model: mujoco.MjModel, body_id: int) -> str:
    return model.body(body_id).name or f"body_{body_id}"


def body_entity(model: mujoco.MjModel, body_id: int) -> str:
    """Entity path of a body: ``world/<body name or body_<i>>``."""
    return f"{WORLD}/{_part(_body_name(model, body_id))}"


def _body_entity_by_name(name: str) -> str:
    return f"{WORLD}/{_part(name)}"


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
        ),
        collapse_panels=False,
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
        if njnt == 1 and model.jnt_type[jnt0] == mujoco.mjtJoint.mjJNT_FREE:
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
            jtype = model.jnt_type[j]
            if jtype == mujoco.mjtJoint.mjJNT_SLIDE:
                dq = (qpos[:, adr] - model.qpos0[adr])[:, None]
                p = p + _quat_rotate(q, model.jnt_axis[j]) * dq
            elif jtype in (mujoco.mjtJoint.mjJNT_HINGE, mujoco.mjtJoint.mjJNT_BALL):
                anchor = _quat_rotate(q, model.jnt_pos[j]) + p
                if jtype == mujoco.mjtJoint.mjJNT_BALL:
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
# Logging
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
        # MuJoCo: centred, along local z, half-length size[1]; rerun: from the origin up +z.
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
        hx = size[0] if size[0] > 0 else INFINITE_PLANE_HALF_SIZE
        hy = size[1] if size[1] > 0 else INFINITE_PLANE_HALF_SIZE
        quad = np.array([[-hx, -hy, 0.0], [hx, -hy, 0.0], [hx, hy, 0.0], [-hx, hy, 0.0]])
        return rr.Mesh3D(
            vertex_positions=quad,
            triangle_indices=[[0, 1, 2], [0, 2, 3]],
            vertex_normals=np.tile([0.0, 0.0, 1.0], (4, 1)),
            albedo_factor=color[0],
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


@dataclass(frozen=True)
class _Geometry:
    entity: str
    shape: Any
    pose: rr.Transform3D


def _model_geometry(model: mujoco.MjModel) -> list[_Geometry]:
    out = []
    for g in range(model.ngeom):
        if int(model.geom_group[g]) not in VISIBLE_GEOM_GROUPS:
            continue
        with _strict():
            shape = _geom_shape(model, g)
            if shape is None:
                gtype = mujoco.mjtGeom(int(model.geom_type[g])).name
                warnings.warn(f"geom {g} ({gtype}): no rerun equivalent, not logged", stacklevel=3)
                continue
            pose = rr.Transform3D(
                translation=model.geom_pos[g],
                quaternion=rr.Quaternion(xyzw=mujoco_to_rerun_quat(model.geom_quat[g])),
            )
        out.append(_Geometry(geom_entity(model, g), shape, pose))
    return out


def _log_geometry(rec: rr.RecordingStream, geometry: Sequence[_Geometry]) -> None:
    with _strict():
        rec.log(WORLD, rr.ViewCoordinates.RIGHT_HAND_Z_UP, static=True, strict=True)
        for item in geometry:
            rec.log(item.entity, item.pose, item.shape, static=True, strict=True)


def log_model_geometry(rec: rr.RecordingStream, model: mujoco.MjModel) -> None:
    """Log every visible geom (groups 0-2) as a static shape under its body, once per recording.

    Each geom entity carries its shape, MuJoCo colour and a static pose in its body; the body
    entity above it receives the per-step pose (`log_episode`), so the scene moves as one.
    """
    _log_geometry(rec, _model_geometry(model))


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
    bodies: tuple[tuple[int, str], ...]  # (body id, entity path), world body excluded
    cube_z: int  # index in the physics state
    fingers: tuple[int, int]  # indices in the physics state
    contact_normal: tuple[int, int]  # indices in sensordata

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
            fingers=fingers,  # type: ignore[arg-type]
            contact_normal=tuple(normals),  # type: ignore[arg-type]
        )


def _check_shapes(
    layout: _Layout, physics: np.ndarray, sensordata: np.ndarray, ctrl: np.ndarray
) -> None:
    nstep = ctrl.shape[0] if ctrl.ndim == 2 else -1
    expected = {
        "ctrl": (ctrl, (nstep, layout.nu)),
        "physics": (physics, (nstep, layout.nstate)),
        "sensordata": (sensordata, (nstep, layout.nsensordata)),
    }
    for name, (arr, shape) in expected.items():
        if arr.shape != shape or nstep < 1:
            raise ValueError(f"{name}: expected shape {shape} (n_steps from ctrl), got {arr.shape}")


def _log_episode(
    rec: rr.RecordingStream,
    model: mujoco.MjModel,
    layout: _Layout,
    *,
    physics: np.ndarray,
    sensordata: np.ndarray,
    ctrl: np.ndarray,
    log_every: int,
) -> None:
    physics = np.asarray(physics, dtype=np.float64)
    sensordata = np.asarray(sensordata, dtype=np.float64)
    ctrl = np.asarray(ctrl, dtype=np.float64)
    _check_shapes(layout, physics, sensordata, ctrl)
    steps = logged_steps(ctrl.shape[0], log_every)
    rows = physics[steps]
    time_ns = np.rint(rows[:, STATE_TIME] * 1e9).astype(np.int64)
    # rerun's own float path truncates (0.006 s -> 5999999 ns); round here instead.
    indexes = [
        rr.TimeColumn(TIMELINE, duration=time_ns.astype("timedelta64[ns]")),
        rr.TimeColumn(STEP_TIMELINE, sequence=steps),
    ]
    positions, orientations = _body_frames(model, rows[:, STATE_QPOS : STATE_QPOS + model.nq])
    transforms = []
    for body, entity in layout.bodies:
        translation = np.broadcast_to(positions[body], (len(steps), 3))
        quat = orientations[body]
        if quat.ndim == 1 and np.allclose(quat, (1.0, 0.0, 0.0, 0.0), rtol=0, atol=1e-12):
            # never rotates: translation only (Transform3D defaults to no rotation)
            columns = rr.Transform3D.columns(translation=translation)
        else:
            xyzw = mujoco_to_rerun_quat(np.broadcast_to(quat, (len(steps), 4)))
            columns = rr.Transform3D.columns(translation=translation, quaternion=xyzw)
        transforms.append((entity, columns))
    scalars: list[tuple[str, np.ndarray]] = [
        (CUBE_HEIGHT, rows[:, layout.cube_z]),
        (FINGER_OPENING, rows[:, list(layout.fingers)].mean(axis=1)),
    ]
    for name, k in zip(CTRL_NAMES, (CTRL_X, CTRL_Y, CTRL_Z, CTRL_GRIPPER), strict=True):
        scalars.append((f"{CTRL}/{name}", ctrl[steps, k]))
    normal = np.abs(sensordata[steps][:, list(layout.contact_normal)])
    for side, column in zip(CONTACT_SIDES, normal.T, strict=True):
        scalars.append((f"{CONTACT_FORCE}/{side}", column))

    with _strict():
        for entity, columns in transforms:
            rec.send_columns(entity, indexes=indexes, columns=columns, strict=True)
        for entity, values in scalars:
            rec.send_columns(
                entity,
                indexes=indexes,
                columns=rr.Scalars.columns(scalars=np.ascontiguousarray(values)),
                strict=True,
            )


def log_episode(
    rec: rr.RecordingStream,
    model: mujoco.MjModel,
    *,
    physics: np.ndarray,
    sensordata: np.ndarray,
    ctrl: np.ndarray,
    log_every: int,
) -> None:
    """Log one episode's motion and signals, every `log_every`-th step and the last.

    Logs body poses (computed from qpos by `body_poses`) and the scalar plots, one
    `send_columns` call per entity on the `sim_time` and `step` timelines.

    Args:
      rec: the episode's recording.
      model: the model the episode ran on.
      physics: (n_steps, nstate) mjSTATE_FULLPHYSICS after each step.
      sensordata: (n_steps, nsensordata) sensors after each step.
      ctrl: (n_steps, nu) the ctrl applied for each step.
      log_every: log every `log_every`-th step (>= 1); the last step is always logged.
    """
    _log_episode(
        rec,
        model,
        _Layout.of(model),
        physics=physics,
        sensordata=sensordata,
        ctrl=ctrl,
        log_every=log_every,
    )


# --------------------------------------------------------------------------------------------
# Files holding many recordings
# --------------------------------------------------------------------------------------------


@dataclass(frozen=True, eq=False)
class EpisodeRecord:
    """One episode to record: its initial state, trajectories and outcome."""

    state: InitialState
    physics: np.ndarray  # (n_steps, nstate)
    sensordata: np.ndarray  # (n_steps, nsensordata)
    success: bool
    final_height: float
    failure_category: str | None = None


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
    """Environment for the rerun CLI: `CI` set keeps rerun 0.41 from writing analytics files."""
    return {**os.environ, "CI": os.environ.get("CI", "1")}


class _RrdFileWriter:
    """Writes encoded rerun streams, one after another, as one valid .rrd file.

    Feeds them to ``rerun rrd route -o <path>``, which re-frames them as a single stream with a
    single footer, without decoding the payloads.
    """

    def __init__(self, path: Path) -> None:
        self._stderr: IO[bytes] = tempfile.TemporaryFile()
        self._proc = subprocess.Popen(
            [_rerun_cli(), "rrd", "route", "-o", str(path)],
            stdin=subprocess.PIPE,
            stdout=subprocess.DEVNULL,
            stderr=self._stderr,
            env=_cli_env(),
        )

    def write(self, encoded: bytes) -> None:
        assert self._proc.stdin is not None
        try:
            self._proc.stdin.write(encoded)
        except BrokenPipeError:
            self._proc.wait()
            raise RuntimeError(f"rerun rrd route stopped early: {self._error_text()}") from None

    def close(self) -> None:
        assert self._proc.stdin is not None
        try:
            self._proc.stdin.close()
        except BrokenPipeError:
            pass
        code = self._proc.wait()
        if code != 0:
            raise RuntimeError(f"rerun rrd route failed (exit {code}): {self._error_text()}")
        self._stderr.close()

    def abort(self) -> None:
        self._proc.kill()
        self._proc.wait()
        self._stderr.close()

    def _error_text(self) -> str:
        self._stderr.seek(0)
        text = self._stderr.read().decode("utf-8", "replace").strip()
        return text[-2000:] or "no output"


@contextmanager
def _rrd_file(path: Path) -> Iterator[_RrdFileWriter]:
    writer = _RrdFileWriter(path)
    try:
        yield writer
    except BaseException:
        writer.abort()
        raise
    writer.close()


@contextmanager
def _encoded_recording(
    application_id: str, recording_id: str, name: str
) -> Iterator[tuple[rr.RecordingStream, list[bytes]]]:
    """A recording encoded in memory; on exit its bytes land in the yielded list."""
    rec = rr.RecordingStream(application_id, recording_id=recording_id, send_properties=False)
    if not rec.is_enabled():
        raise RuntimeError("rerun logging is disabled (is RERUN=off set in the environment?)")
    stream = rec.binary_stream()
    out: list[bytes] = []
    try:
        rec.send_recording_name(name)
        yield rec, out
        encoded = stream.read(flush=True)
        if not encoded:
            raise RuntimeError(f"recording {recording_id!r}: rerun produced no data")
        out.append(encoded)
    finally:
        del stream
        del rec


def _blueprint_bytes(application_id: str) -> bytes:
    """`default_blueprint` encoded as a stream of its own (an .rbl file's content).

    Kept out of the recordings' streams: `rerun rrd route` 0.41 can panic on a stream that
    mixes a blueprint store into a recording's sink.
    """
    with tempfile.TemporaryDirectory(prefix="mjtrial-blueprint-") as tmp:
        path = Path(tmp) / "blueprint.rbl"
        default_blueprint().save(application_id, path)
        return path.read_bytes()


def _stamp_json(stamp: Mapping[str, Any]) -> str:
    if not isinstance(stamp, Mapping) or "mjtrial_stamp" not in stamp:
        raise ValueError(
            "not an mjtrial provenance stamp (missing 'mjtrial_stamp'); use make_stamp"
        )
    return json.dumps(dict(stamp), allow_nan=False)


def _send_property(rec: rr.RecordingStream, name: str, fields: Mapping[str, Any]) -> None:
    # One-element lists: rerun converts bare Python scalars ~10x slower (exception paths).
    with _strict():
        rec.send_property(
            name, rr.AnyValues(**{k: v if isinstance(v, list) else [v] for k, v in fields.items()})
        )


def _send_json_property(rec: rr.RecordingStream, name: str, text: str) -> None:
    _send_property(rec, name, {_JSON_FIELD: text})


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

    Episodes are consumed one at a time (memory holds one encoded episode), so `episodes` may be
    a generator over rollout batches. Recording ids are deterministic
    (`episode_recording_id`), each recording carries the properties `episode` and
    `provenance`, and the file carries `default_blueprint`.

    Returns:
      the number of recordings written (>= 1; no episodes is an error).
    """
    path = Path(path)
    stamp_text = _stamp_json(stamp)
    layout = _Layout.of(model)
    geometry = _model_geometry(model)
    ctrl = np.asarray(ctrl, dtype=np.float64)
    logged_steps(ctrl.shape[0] if ctrl.ndim == 2 else 0, log_every)  # validate early
    seen: set[int] = set()
    with atomic_path(path) as tmp, _rrd_file(tmp) as out:
        for ep in episodes:
            sid = int(ep.state.state_id)
            if sid in seen:
                raise ValueError(f"{condition}: state {sid} appears twice among the episodes")
            rid = episode_recording_id(condition, sid)
            if not seen:
                out.write(_blueprint_bytes(application_id))
            with _encoded_recording(
                application_id, rid, episode_recording_name(condition, sid)
            ) as (rec, encoded):
                _send_episode_properties(rec, ep, condition=condition, log_every=log_every)
                _send_json_property(rec, PROVENANCE_PROPERTY, stamp_text)
                _log_geometry(rec, geometry)
                _log_episode(
                    rec,
                    model,
                    layout,
                    physics=ep.physics,
                    sensordata=ep.sensordata,
                    ctrl=ctrl,
                    log_every=log_every,
                )
            out.write(encoded[0])
            seen.add(sid)
        if not seen:
            raise ValueError(f"{condition}: no episodes to record")
    return len(seen)


def _send_episode_properties(
    rec: rr.RecordingStream, ep: EpisodeRecord, *, condition: str, log_every: int
) -> None:
    s = ep.state
    values: dict[str, Any] = {
        "condition": str(condition),
        "state_id": int(s.state_id),
        "dx": float(s.dx),
        "dy": float(s.dy),
        "yaw": float(s.yaw),
        "mass": float(s.mass),
        "success": bool(ep.success),
        "final_height": float(ep.final_height),
        "log_every": int(log_every),
    }
    if ep.failure_category is not None:  # absent means None: rerun has no typed null
        values["failure_category"] = str(ep.failure_category)
    _send_property(rec, EPISODE_PROPERTY, values)


def write_failures_rrd(
    path: str | os.PathLike[str],
    sources: Sequence[str | os.PathLike[str]],
    *,
    stamp: Mapping[str, Any],
    application_id: str = APPLICATION_ID,
) -> int:
    """Atomically gather the failed episodes (property success False) of condition .rrd files.

    The file starts with a summary recording (id ``failures``: count, source file names, a table
    of the failures), so it is stamped even when nothing failed. Each failed recording is copied
    chunk for chunk under the id ``failures-<original id>`` (distinct from the original, so both
    files can be open in one viewer); its `provenance` becomes `stamp` and the original stamp is
    kept as `source_provenance`. Memory holds one recording at a time.

    Returns:
      the number of failed episodes written.
    """
    path = Path(path)
    stamp_text = _stamp_json(stamp)
    failures: list[tuple[Path, rr.chunk.StoreEntry, dict[str, Any]]] = []
    for source in map(Path, sources):
        reader = _open(source)
        for entry in reader.recordings():
            props = _properties(reader, entry)
            if props.get("success") is False:
                failures.append((source, entry, props))

    with atomic_path(path) as tmp, _rrd_file(tmp) as out:
        out.write(_blueprint_bytes(application_id))
        name = f"failures: {len(failures)} episode(s) from {len(sources)} file(s)"
        with _encoded_recording(application_id, FAILURES_SUMMARY, name) as (rec, encoded):
            _send_json_property(rec, PROVENANCE_PROPERTY, stamp_text)
            sources_json = json.dumps([Path(s).name for s in sources])
            _send_property(
                rec, FAILURES_PROPERTY, {"n_failures": len(failures), "sources": sources_json}
            )
            with _strict():
                rec.log(FAILURES_SUMMARY, _failures_table(failures), static=True, strict=True)
        out.write(encoded[0])

        for source, entry, props in failures:
            reader = _open(source)
            rid = _RECORDING_ID_PREFIX_FAILURES + entry.recording_id
            with _encoded_recording(application_id, rid, props.get("name", rid)) as (rec, encoded):
                chunks = reader.store(store=entry).stream()
                chunks = chunks.drop(content=f"{_PROPERTIES}/**")
                rr.send_chunks(chunks, recording=rec)
                _copy_properties(reader, entry, rec)
                _send_json_property(rec, PROVENANCE_PROPERTY, stamp_text)
                original = props.get(PROVENANCE_PROPERTY)
                if original is not None:
                    _send_json_property(rec, SOURCE_PROVENANCE_PROPERTY, json.dumps(original))
            out.write(encoded[0])
    return len(failures)


def _copy_properties(
    reader: rr.chunk.RrdReader, entry: rr.chunk.StoreEntry, rec: rr.RecordingStream
) -> None:
    """Re-send every property of `entry` except the name and the provenance stamps."""
    skip = {PROVENANCE_PROPERTY, SOURCE_PROVENANCE_PROPERTY}
    for prop, fields in _raw_properties(reader, entry).items():
        if prop is None or prop in skip:
            continue
        _send_property(rec, prop, fields)


def _failures_table(failures: Sequence[tuple[Path, Any, dict[str, Any]]]) -> rr.TextDocument:
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


def _open(path: str | os.PathLike[str]) -> rr.chunk.RrdReader:
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"{path}: no such .rrd file")
    try:
        return rr.chunk.RrdReader(path)
    except RuntimeError as exc:
        raise ValueError(f"{path}: not a readable .rrd file: {exc}") from exc


def _data_columns(batch: pa.RecordBatch) -> Iterator[tuple[str, pa.Array]]:
    for field, column in zip(batch.schema, batch.columns, strict=True):
        if (field.metadata or {}).get(b"rerun:kind") == b"data":
            yield field.name, column


def _raw_properties(
    reader: rr.chunk.RrdReader, entry: rr.chunk.StoreEntry
) -> dict[str | None, dict[str, Any]]:
    """{property name (None for the recording's own info): {field: value}} of one recording."""
    prefix = _PROPERTIES
    stream = reader.store(store=entry).stream().filter(content=f"{prefix}/**", is_static=True)
    out: dict[str | None, dict[str, Any]] = {}
    for chunk in stream:
        entity = chunk.entity_path
        prop = None if entity == prefix else entity[len(prefix) + 1 :]
        fields = out.setdefault(prop, {})
        batch = chunk.to_record_batch()
        for name, column in _data_columns(batch):
            if len(column) == 0:
                continue
            values = column[len(column) - 1].as_py()  # static: the last row wins
            if values is None:
                continue
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


def _properties(reader: rr.chunk.RrdReader, entry: rr.chunk.StoreEntry) -> dict[str, Any]:
    raw = _raw_properties(reader, entry)
    info = raw.pop(None, {})
    out: dict[str, Any] = {
        "recording_id": entry.recording_id,
        "application_id": entry.application_id,
        "name": info.get("RecordingInfo:name"),
    }
    if EPISODE_PROPERTY in raw:
        out.update({"failure_category": None, **raw.pop(EPISODE_PROPERTY)})
    if FAILURES_PROPERTY in raw:
        fields = dict(raw.pop(FAILURES_PROPERTY))
        if "sources" in fields:
            fields["sources"] = json.loads(fields["sources"])
        out.update(fields)
    for prop in (PROVENANCE_PROPERTY, SOURCE_PROVENANCE_PROPERTY):
        if prop in raw:
            out[prop] = _parse_json_property(raw.pop(prop), f"{entry.recording_id}: {prop}")
    for prop, fields in raw.items():  # anything else, kept under its own name
        out[prop] = fields
    return out


def list_recordings(path: str | os.PathLike[str]) -> list[dict[str, Any]]:
    """Properties of each recording in the file, in file order.

    Each dict has `recording_id`, `application_id`, `name`; episode recordings add condition,
    state_id, dx, dy, yaw, mass, success, final_height, failure_category, log_every; every
    recording written here has `provenance` (the stamp, parsed).
    """
    reader = _open(path)
    return [_properties(reader, entry) for entry in reader.recordings()]


def read_rrd_stamp(path: str | os.PathLike[str]) -> dict[str, Any] | None:
    """The file's provenance stamp: the `provenance` property of its first recording.

    Returns None when the file has no recording or the first recording has no stamp.
    """
    reader = _open(path)
    entries = reader.recordings()
    if not entries:
        return None
    raw = _raw_properties(reader, entries[0])
    return _parse_json_property(raw.get(PROVENANCE_PROPERTY), f"{path}: provenance")


def _find_episode(
    reader: rr.chunk.RrdReader, path: Path, condition: str, state_id: int
) -> rr.chunk.StoreEntry:
    rid = episode_recording_id(condition, state_id)
    wanted = (rid, _RECORDING_ID_PREFIX_FAILURES + rid)
    entries = reader.recordings()
    for entry in entries:
        if entry.recording_id in wanted:
            return entry
    raise KeyError(
        f"{path}: no recording of condition {condition!r}, state {state_id} "
        f"(recording id {rid!r}); the file holds {len(entries)} recording(s)"
    )


def _column_values(column: pa.Array, width: int) -> np.ndarray:
    """A list<...> column with one instance per row as an (n, width) float64 array."""
    lengths = pc.list_value_length(column).to_numpy(zero_copy_only=False)
    if not np.all(lengths == 1):
        raise ValueError("expected exactly one value per row")
    values = column.flatten()
    if pa.types.is_fixed_size_list(values.type):
        values = values.flatten()
    return values.to_numpy(zero_copy_only=False).astype(np.float64).reshape(-1, width)


def read_episode(
    path: str | os.PathLike[str], *, condition: str, state_id: int
) -> dict[str, np.ndarray]:
    """One episode's logged series, sorted by step.

    Returns a dict of arrays over the n logged steps: step (n,) physics step index; time (n,)
    simulated seconds (rerun keeps integer nanoseconds: exact to 1 ns); cube_position (n, 3)
    and cube_quat_wxyz (n, 4) (rerun stores transforms as float32); finger_opening,
    cube_height (n,); ctrl (n, 4); contact_force (n, 2) left, right normal force (float64,
    exactly as logged).

    Raises:
      KeyError: the file has no recording of that condition and state.
    """
    path = Path(path)
    reader = _open(path)
    entry = _find_episode(reader, path, condition, state_id)
    cube = _body_entity_by_name(CUBE_BODY)
    wanted: dict[str, list[tuple[str, int]]] = {
        cube: [("Transform3D:translation", 3), ("Transform3D:quaternion", 4)],
        CUBE_HEIGHT: [("Scalars:scalars", 1)],
        FINGER_OPENING: [("Scalars:scalars", 1)],
        **{f"{CTRL}/{n}": [("Scalars:scalars", 1)] for n in CTRL_NAMES},
        **{f"{CONTACT_FORCE}/{s}": [("Scalars:scalars", 1)] for s in CONTACT_SIDES},
    }
    parts: dict[str, list[dict[str, np.ndarray]]] = {e: [] for e in wanted}
    stream = reader.store(store=entry).stream()
    stream = stream.filter(content=[f"/{e}" for e in wanted], has_timeline=STEP_TIMELINE)
    for chunk in stream:
        entity = chunk.entity_path.lstrip("/")
        if entity not in wanted:
            continue
        batch = chunk.to_record_batch()
        names = batch.schema.names
        part = {
            "step": batch.column(names.index(STEP_TIMELINE)).to_numpy(zero_copy_only=False),
            "time_ns": batch.column(names.index(TIMELINE)).cast(pa.int64()).to_numpy(),
        }
        for component, width in wanted[entity]:
            if component in names:
                part[component] = _column_values(batch.column(names.index(component)), width)
        parts[entity].append(part)

    series: dict[str, dict[str, np.ndarray]] = {}
    for entity, chunks in parts.items():
        if not chunks:
            raise ValueError(f"{path}: recording {entry.recording_id!r} has no data at {entity}")
        merged = {k: np.concatenate([c[k] for c in chunks]) for k in chunks[0]}
        order = np.argsort(merged["step"], kind="stable")
        series[entity] = {k: v[order] for k, v in merged.items()}

    steps = series[CUBE_HEIGHT]["step"]
    for entity, s in series.items():
        if not np.array_equal(s["step"], steps):
            raise ValueError(f"{path}: {entity} is not logged at the same steps as {CUBE_HEIGHT}")

    def scalar(entity: str) -> np.ndarray:
        return series[entity]["Scalars:scalars"][:, 0]

    return {
        "step": steps.astype(np.int64),
        "time": series[CUBE_HEIGHT]["time_ns"] / 1e9,
        "cube_position": series[cube]["Transform3D:translation"],
        "cube_quat_wxyz": rerun_to_mujoco_quat(series[cube]["Transform3D:quaternion"]),
        "finger_opening": scalar(FINGER_OPENING),
        "ctrl": np.stack([scalar(f"{CTRL}/{n}") for n in CTRL_NAMES], axis=1),
        "cube_height": scalar(CUBE_HEIGHT),
        "contact_force": np.stack([scalar(f"{CONTACT_FORCE}/{s}") for s in CONTACT_SIDES], axis=1),
    }
