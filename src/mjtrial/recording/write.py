"""Writing episodes' recordings: a condition's folder, or one episode's file.

The main thread only keeps each episode's logged rows; a writer thread builds the recordings
of `_GROUP` episodes at once, straight from Arrow columns (the chunks every recording shares are
built once and given a fresh chunk id per recording), and writes each with
``ChunkStore.write_rrd`` while the main thread runs the next rollouts (``mujoco.rollout``
releases the GIL); a third thread fsyncs the files.

Why this shape: size, and the time it takes to write. In a file, every entity costs each
recording a chunk of its own (~1-2 kB of schema even for one box), and every time-series chunk
16 bytes of row id and 8 of timestamp per row; every (entity, component) pair costs each
recording ~0.5 kB of index in the file's footer, which ``ChunkStore.write_rrd`` builds for every
recording. So geoms are instances of one archetype on their body's entity, not entities of their
own; the signals share their body's time-series chunk; the episode's fields are one struct;
solid shapes are a default of the 3D view rather than a component of each shape; and a child
body's pose in its parent keeps its constant components constant (a body that slides along one
axis), which compresses well.
"""

from __future__ import annotations

import hashlib
import json
import os
import queue
import threading
import time
from collections.abc import Callable, Iterable, Iterator, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import mujoco
import numpy as np
import pyarrow as pa
from rerun.chunk import ChunkStore

from mjtrial.files.atomic import atomic_directory, atomic_path, fsync_file
from mjtrial.provenance import RECORDING_FOLDER_BLUEPRINT, RECORDING_FOLDER_STAMP, write_json
from mjtrial.recording.arrow import (
    archetype_columns,
    chunks,
    component_field,
    property_columns,
    record_batch,
    recording_name_field,
    strict,
)
from mjtrial.recording.names import (
    APPLICATION_ID,
    EPISODE_COMPONENT,
    EPISODE_PROPERTY,
    JSON_FIELD,
    MESH_STORE_FILE,
    MESH_STORE_PREFIX,
    MESHES_PROPERTY,
    PROPERTIES,
    PROVENANCE_PROPERTY,
    default_blueprint,
    episode_recording_id,
    episode_recording_name,
    file_name,
    logged_steps,
)
from mjtrial.recording.route import rrd_output, save_blueprint, write_store
from mjtrial.recording.scene import mesh_scene, static_scene
from mjtrial.recording.series import Chunker, Signal
from mjtrial.sim import phases


@dataclass(frozen=True, eq=False)
class EpisodeRecord:
    """One episode to record: its initial state's values, trajectories and outcome.

    `values` are the state parameters (name -> value) and `measures` the outcome's recorded
    measures (the task's `Measure(recorded=True)`), both in the order the recording keeps.
    """

    state_id: int
    values: Mapping[str, float]
    physics: np.ndarray  # (n_steps, nstate) mjSTATE_FULLPHYSICS after each step
    sensordata: np.ndarray  # (n_steps, nsensordata)
    ctrl: np.ndarray  # (n_steps, nu) the ctrl applied before each step
    success: bool
    measures: Mapping[str, float]
    failure_category: str | None = None
    mocap: np.ndarray | None = None  # (n_steps, nmocap, 7) targets a policy moved, or None


def stamp_json(stamp: Mapping[str, Any]) -> str:
    """A provenance stamp as the JSON text of a recording's `provenance` property."""
    if not isinstance(stamp, Mapping) or "mjtrial_stamp" not in stamp:
        raise ValueError(
            "not an mjtrial provenance stamp (missing 'mjtrial_stamp'); use make_stamp"
        )
    return json.dumps(dict(stamp), allow_nan=False)


# The `episode` property is one component holding a struct, not one component per field: every
# component costs each recording ~0.5 kB of index in the file's footer. The struct keeps the
# names and types (failure_category is null when the episode did not fail): condition,
# state_id, the state's values, success, the recorded measures, failure_category, log_every
# and n_steps.
def episode_field(state_names: Sequence[str], measure_names: Sequence[str]) -> pa.Field:
    """The `episode` property's field for a task's state parameters and recorded measures."""
    number = [pa.field(n, pa.float64(), nullable=False) for n in (*state_names,)]
    measured = [pa.field(n, pa.float64(), nullable=False) for n in measure_names]
    struct = pa.struct(
        [
            pa.field("condition", pa.string(), nullable=False),
            pa.field("state_id", pa.int64(), nullable=False),
            *number,
            pa.field("success", pa.bool_(), nullable=False),
            *measured,
            pa.field("failure_category", pa.string()),
            pa.field("log_every", pa.int64(), nullable=False),
            pa.field("n_steps", pa.int64(), nullable=False),
        ]
    )
    return component_field(EPISODE_COMPONENT, struct, f"{PROPERTIES}/{EPISODE_PROPERTY}")


def _episode_fields(ep: EpisodeRecord, condition: str, n_steps: int, log_every: int) -> dict:
    return {
        "condition": str(condition),
        "state_id": int(ep.state_id),
        **{k: float(v) for k, v in ep.values.items()},
        "success": bool(ep.success),
        **{k: float(v) for k, v in ep.measures.items()},
        "failure_category": None if ep.failure_category is None else str(ep.failure_category),
        "log_every": int(log_every),
        "n_steps": int(n_steps),
    }


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
    ctrl: np.ndarray  # logged rows of ctrl
    geometry: list[Any] | None = None  # the episode's own scene's columns, where it differs
    mocap: np.ndarray | None = None  # logged rows of the mocap targets, when a policy moves them


_GROUP = 32  # episodes whose recordings are built at once (numpy's cost is per call)
_QUEUE = 128  # episodes waiting for the writer thread, at most


@dataclass(frozen=True)
class RecordingSpec:
    """What every recording of a task shares: its model, the signals it plots, the names of the
    episode property's state values and measures, the episode length and the logging rate."""

    model: mujoco.MjModel
    signals: Sequence[Signal]
    state_names: Sequence[str]
    measure_names: Sequence[str]
    n_steps: int
    log_every: int
    # `episode_model(values)`: the episode's own model, for a task whose state parameters edit
    # it (a goal geom moved per episode); None when every episode runs on `model` itself
    episode_model: Callable[[Mapping[str, float]], mujoco.MjModel] | None = None
    moves_mocap: bool = False  # a policy moves the mocap bodies: their targets logged per step


# What a recording's static scene is drawn from: an episode whose model differs here gets its own.
SCENE_FIELDS = (
    *("geom_type", "geom_pos", "geom_quat", "geom_size", "geom_rgba", "geom_dataid"),
    *("geom_bodyid", "geom_group", "body_pos", "body_quat", "mat_rgba"),
)


def episode_geometry(
    model: mujoco.MjModel,
    nominal: mujoco.MjModel,
    *,
    meshes: bool = True,
    moving_mocap: bool = False,
) -> list[Any] | None:
    """The static scene's columns of an episode's own model, or None when it draws as `nominal`
    (a mass drawn per episode changes no drawing; a goal geom moved per episode does). Without
    `meshes`, the scene leaves its meshes out (a mesh store has them)."""
    if all(np.array_equal(getattr(model, f), getattr(nominal, f)) for f in SCENE_FIELDS):
        return None
    scene = static_scene(model, meshes=meshes, moving_mocap=moving_mocap)
    return [c for e, a in scene for c in archetype_columns(e, a)]


@dataclass(frozen=True)
class MeshStore:
    """A model's meshes as a recording of their own, stored once for many episodes'
    recordings (each names it in its `meshes` property): a `Mesh3D` on each body's entity, as
    a recording with its meshes inline has them. Its recording id holds its content's digest,
    so a recording never picks up another model's meshes."""

    recording_id: str
    columns: list[Any]

    def chunks(self) -> list[Any]:
        """Its chunks, under fresh chunk ids."""
        return chunks(self.columns)


def mesh_store(model: mujoco.MjModel, stamp_text: str) -> MeshStore | None:
    """The mesh store of `model` (None: it draws no mesh), stamped with `stamp_text`."""
    columns = [c for e, a in mesh_scene(model) for c in archetype_columns(e, a)]
    if not columns:
        return None
    digest = hashlib.sha256()
    for field, values in columns:
        digest.update(field.name.encode())
        for buffer in values.buffers():
            if buffer is not None:
                digest.update(buffer)
    recording_id = MESH_STORE_PREFIX + digest.hexdigest()[:16]
    name = recording_name_field()
    columns += [
        (name, pa.array([[f"meshes {digest.hexdigest()[:16]}"]], type=name.type)),
        *property_columns(PROVENANCE_PROPERTY, {JSON_FIELD: stamp_text}),
    ]
    return MeshStore(recording_id, columns)


class EpisodeStores:
    """Builds each episode's recording (a `ChunkStore`) for a task's recordings, a condition
    and a stamp.

    `groups(episodes)` consumes the episodes one at a time (a generator over rollout batches
    will do) and keeps their logged rows until `_GROUP` have come; `build(group)` then builds
    those recordings at once (numpy's and pyarrow's cost is per call).
    """

    def __init__(
        self,
        spec: RecordingSpec,
        *,
        condition: str,
        stamp: Mapping[str, Any],
        share_meshes: bool = False,
    ) -> None:
        stamp_text = stamp_json(stamp)
        self.spec, self.condition = spec, condition
        self.steps = logged_steps(spec.n_steps, spec.log_every)  # validate before any work
        # with `share_meshes`, the meshes go to `meshes` (a recording of their own, written
        # once), which each recording names in its `meshes` property
        self.meshes = mesh_store(spec.model, stamp_text) if share_meshes else None
        inline = self.meshes is None
        self.chunker = chunker = Chunker(
            spec.model, spec.signals, meshes=inline, moving_mocap=spec.moves_mocap
        )
        self.episode_field = episode_field(spec.state_names, spec.measure_names)
        # the same in every recording: geometry, static poses, series names and the stamp
        self.shared = [
            *chunker.styles,
            *property_columns(PROVENANCE_PROPERTY, {JSON_FIELD: stamp_text}),
        ]
        if self.meshes is not None:
            reference = {"recording": self.meshes.recording_id, "file": MESH_STORE_FILE}
            self.shared += property_columns(MESHES_PROPERTY, reference)
        self.constant = chunks([*chunker.geometry, *self.shared])
        self.plots = chunker.plots
        self.blueprint = default_blueprint(chunker.plots)

    def build(self, group: list[_Pending]) -> Iterator[tuple[str, ChunkStore]]:
        """(recording id, store) of each episode of a group from `groups`."""
        n = len(self.steps)
        series = self.chunker.series(
            [(p.rows, p.sensors, p.ctrl) for p in group],
            [p.mocap for p in group] if self.spec.moves_mocap else None,
        )
        name_field = recording_name_field()
        field = self.episode_field
        properties = record_batch(
            [
                (name_field, pa.array([[p.name] for p in group], type=name_field.type)),
                (field, pa.array([[p.fields] for p in group], type=field.type)),
            ]
        )
        for i, ep in enumerate(group):
            with strict():
                recording = [
                    *chunks(properties.slice(i, 1)),
                    # the same data in every recording, each time under a fresh chunk id
                    *(
                        c.with_entity_path(c.entity_path)
                        for c in (
                            self.constant
                            if ep.geometry is None
                            else chunks([*ep.geometry, *self.shared])
                        )
                    ),
                    *chunks(series.slice(i * n, n), temporal=True),
                ]
                store = ChunkStore.from_chunks(recording)
            yield ep.recording_id, store

    def _episode_geometry(self, model: mujoco.MjModel) -> list[Any] | None:
        """`episode_geometry` of an episode's own model; its meshes must be the store's."""
        geometry = episode_geometry(
            model,
            self.spec.model,
            meshes=self.meshes is None,
            moving_mocap=self.spec.moves_mocap,
        )
        if geometry is not None and self.meshes is not None:
            own = mesh_store(model, "")
            if own is None or own.recording_id != self.meshes.recording_id:
                raise ValueError(
                    f"{self.condition}: an episode's own model draws other meshes than the "
                    "task's model; its recordings cannot share a mesh store"
                )
        return geometry

    def groups(self, episodes: Iterable[EpisodeRecord]) -> Iterator[list[_Pending]]:
        """The episodes' logged rows and properties, `_GROUP` episodes at a time."""
        condition, seen, spec = self.condition, set(), self.spec
        group: list[_Pending] = []
        for ep in episodes:
            sid = int(ep.state_id)
            if sid in seen:
                raise ValueError(f"{condition}: state {sid} appears twice among the episodes")
            physics, sensordata, ctrl = self.chunker.trajectory(
                ep.physics, ep.sensordata, ep.ctrl, n_steps=spec.n_steps
            )
            group.append(
                _Pending(
                    recording_id=episode_recording_id(condition, sid),
                    name=episode_recording_name(condition, sid),
                    fields=_episode_fields(ep, condition, spec.n_steps, spec.log_every),
                    rows=physics[self.steps],
                    sensors=sensordata[self.steps],
                    ctrl=ctrl[self.steps],
                    geometry=(
                        None
                        if spec.episode_model is None
                        else self._episode_geometry(spec.episode_model(ep.values))
                    ),
                    mocap=_logged_mocap(ep, spec, self.steps),
                )
            )
            seen.add(sid)
            if len(group) == _GROUP:
                yield group
                group = []
        if group:
            yield group


def _logged_mocap(ep: EpisodeRecord, spec: RecordingSpec, steps: np.ndarray) -> np.ndarray | None:
    """The episode's mocap targets at the logged steps, when a policy moves them."""
    if not spec.moves_mocap:
        return None
    shape = (spec.n_steps, spec.model.nmocap, 7)
    if ep.mocap is None or np.shape(ep.mocap) != shape:
        raise ValueError(f"mocap: expected shape {shape}, got {np.shape(ep.mocap)}")
    return np.asarray(ep.mocap, dtype=np.float64)[steps]


def write_condition_recordings(
    path: str | os.PathLike[str],
    *,
    spec: RecordingSpec,
    condition: str,
    episodes: Iterable[EpisodeRecord],
    stamp: Mapping[str, Any],
    application_id: str = APPLICATION_ID,
) -> int:
    """Atomically write the folder `path`: one .rrd per episode of a condition, and a blueprint.

    Each episode's recording goes to `episode_file_name` (its recording id, e.g.
    ``fast-state-000017.rrd``) and carries the properties `episode` and `provenance`, the
    model's geometry and the episode's series (every `log_every`-th step, and the last). A
    model's meshes are not in them: the folder's ``meshes.rrd`` holds them once (`MeshStore`),
    and each recording names it in its `meshes` property (`read.recording_chunks` puts them
    back; a mesh costs ~100x an episode's motion). The folder's ``blueprint.rbl`` is
    `default_blueprint`, so ``rerun <folder>/*`` opens them all in its layout. Episodes are
    consumed one at a time, so `episodes` may be a generator over rollout batches (see
    `EpisodeStores`); a writer thread writes and fsyncs the recordings (at most `_QUEUE` wait)
    while the caller runs the next rollouts.

    Why a file per episode (not one file per condition): rerun 0.41 can put many recordings in
    one file only by streaming them through ``rerun rrd route``, which merges their indexes
    after the last one, single-threaded (0.6 ms a recording, half the cost of logging), and
    holds them in memory (~0.3 MB a recording). A file per episode costs one `write_rrd` call,
    scales to any number of episodes, and opens or travels on its own.

    Returns:
      the number of recordings written (none: a folder holding its blueprint only).
    """
    builder = EpisodeStores(spec, condition=condition, stamp=stamp, share_meshes=True)
    count = 0
    with atomic_directory(Path(path)) as folder:
        save_blueprint(builder.blueprint, application_id, str(folder / RECORDING_FOLDER_BLUEPRINT))

        # fsync in a thread of its own: the disk's writeback then overlaps the rollouts (an fsync
        # after each write, or of every file at the end, cost the rollout stage more)
        syncer = _Worker(fsync_file, maxsize=0, name="mjtrial-rrd-syncer")

        meshes = builder.meshes

        def write(group: list[_Pending]) -> None:
            """Build and write a group's recordings, while the caller runs the next rollouts;
            the folder's mesh store with the first."""
            nonlocal meshes
            began = time.perf_counter(), time.thread_time()
            if meshes is not None:
                target = folder / MESH_STORE_FILE
                with strict():
                    ChunkStore.from_chunks(meshes.chunks()).write_rrd(
                        target, application_id=application_id, recording_id=meshes.recording_id
                    )
                syncer.put(target)
                meshes = None
            for recording_id, store in builder.build(group):
                target = folder / file_name(recording_id)
                with strict():
                    store.write_rrd(
                        target,
                        application_id=application_id,
                        recording_id=recording_id,
                    )
                syncer.put(target)
            phases.add(
                "recording (writer thread)",
                time.perf_counter() - began[0],
                time.thread_time() - began[1],
            )

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
        contents = {"condition": condition, "recordings": count, "plots": builder.plots}
        if builder.meshes is not None and count:
            contents["meshes"] = MESH_STORE_FILE
        write_json(
            contents,
            folder / RECORDING_FOLDER_STAMP,
            stamp,
        )
    return count


def write_episode_recording(
    path: str | os.PathLike[str],
    *,
    spec: RecordingSpec,
    condition: str,
    episode: EpisodeRecord,
    stamp: Mapping[str, Any],
    application_id: str = APPLICATION_ID,
) -> None:
    """Atomically write one episode's recording, and `default_blueprint`, to the file `path`.

    The recording is the one `write_condition_recordings` makes; the blueprint travels in the
    same file (through ``rerun rrd route``), so ``rerun <path>`` opens it in its layout.
    """
    builder = EpisodeStores(spec, condition=condition, stamp=stamp)
    path = Path(path)
    [group] = builder.groups([episode])
    [(recording_id, store)] = builder.build(group)
    with atomic_path(path) as tmp, rrd_output(tmp, application_id, builder.blueprint) as out:
        write_store(out, store, application_id=application_id, recording_id=recording_id)
