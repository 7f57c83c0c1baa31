"""Reading recordings back, with rerun's own reader: properties, stamps and time series."""

from __future__ import annotations

import json
import os
import warnings
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow as pa
import pyarrow.compute as pc
from rerun.chunk import Chunk, RrdReader, StoreEntry

from mjtrial.provenance import RECORDING_FOLDER_STAMP, read_stamp
from mjtrial.provenance.recording_folders import rebuild_hint
from mjtrial.recording.arrow import (
    QUATERNION,
    RECORDING_NAME,
    SCALARS,
    SERIES_NAMES,
    TRANSLATION,
    column,
    data_columns,
)
from mjtrial.recording.names import (
    CLOSEST_CALLS_SUMMARY,
    EPISODE_COMPONENT,
    EPISODE_PROPERTY,
    FAILURE_PREFIX,
    FAILURES_PROPERTY,
    FAILURES_SUMMARY,
    JSON_FIELD,
    MESH_STORE_FILE,
    MESH_STORE_PREFIX,
    MESHES_PROPERTY,
    PROPERTIES,
    PROVENANCE_PROPERTY,
    SOURCE_PROVENANCE_PROPERTY,
    TIMELINE,
    episode_file_name,
    episode_recording_id,
    logged_steps,
)
from mjtrial.recording.scene import rerun_to_mujoco_quat


def recording_files(path: str | os.PathLike[str]) -> list[Path]:
    """The .rrd files of `path`: itself, or the .rrd files of a folder (but its mesh store), in
    name order."""
    path = Path(path)
    if path.is_dir():
        return sorted(p for p in path.glob("*.rrd") if p.is_file() and p.name != MESH_STORE_FILE)
    if not path.is_file():
        raise FileNotFoundError(f"{path}: no such .rrd file or folder of .rrd files")
    return [path]


def open_rrd(path: str | os.PathLike[str]) -> RrdReader:
    """rerun's reader of a .rrd file, with errors that name the file. rerun reads a file
    lazily, so its index is read here: a truncated or damaged file is one `ValueError` naming
    it, not a traceback from whichever read comes first."""
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"{path}: no such .rrd file{rebuild_hint(path)}")
    try:
        # a file without its footer (cut short) is read by a whole-file scan, with a warning
        # on the console, and then cannot give a store: every file mjtrial writes has one
        with warnings.catch_warnings(record=True) as said:
            warnings.simplefilter("always")
            reader = RrdReader(path)
        reader.recordings()  # a frame cut short: rerun's own words
        if any("no footer" in str(w.message) for w in said):
            raise ValueError("it has no footer, which every file written whole has")
    except (RuntimeError, ValueError, OSError) as exc:
        why = " ".join(str(exc).split()).replace(f"Failed to read RRD file at {path}: ", "")
        raise ValueError(
            f"{path}: not a readable .rrd file (truncated or damaged: {why}){rebuild_hint(path)}"
        ) from exc
    return reader


def raw_properties(reader: RrdReader, entry: StoreEntry) -> dict[str | None, dict[str, Any]]:
    """{property name (None: the recording's own info): {field: value}} of one recording."""
    stream = reader.store(store=entry).stream().filter(content=f"{PROPERTIES}/**", is_static=True)
    out: dict[str | None, dict[str, Any]] = {}
    for chunk in stream:
        entity = chunk.entity_path
        prop = None if entity == PROPERTIES else entity[len(PROPERTIES) + 1 :]
        fields = out.setdefault(prop, {})
        for field, values in data_columns(chunk.to_record_batch()):
            if len(values) == 0:
                continue
            last = values[len(values) - 1].as_py()  # static: the last row wins
            if last is not None:
                fields[field.name] = last[0] if len(last) == 1 else last
    return out


def _episode_property(fields: Mapping[str, Any]) -> dict[str, Any]:
    """The fields of a recording's `episode` property: one struct."""
    return dict(fields.get(EPISODE_COMPONENT) or {})


def parse_json_property(fields: Mapping[str, Any] | None, what: str) -> dict[str, Any] | None:
    if not fields or JSON_FIELD not in fields:
        return None
    try:
        value = json.loads(fields[JSON_FIELD])
    except ValueError as exc:
        raise ValueError(f"corrupt {what} property: {exc}") from exc
    if not isinstance(value, dict):
        raise ValueError(f"corrupt {what} property: not a JSON object")
    return value


def properties(reader: RrdReader, entry: StoreEntry) -> dict[str, Any]:
    """One recording's ids, name and properties, as `list_recordings` gives them."""
    raw = raw_properties(reader, entry)
    info = raw.pop(None, {})
    out: dict[str, Any] = {
        "recording_id": entry.recording_id,
        "application_id": entry.application_id,
        "name": info.get(RECORDING_NAME),
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
            out[prop] = parse_json_property(raw.pop(prop), f"{entry.recording_id}: {prop}")
    for prop, fields in raw.items():  # anything else, under its own name
        out[str(prop)] = fields
    return out


def list_recordings(path: str | os.PathLike[str]) -> list[dict[str, Any]]:
    """Properties of each recording in the file (or the folder's files), in file order.

    Each dict has recording_id, application_id, name and provenance (the stamp, parsed).
    Episode recordings add condition, state_id, the state's values, success, the task's
    recorded measures, failure_category (None if absent), log_every, n_steps; copies in
    failures.rrd add source_provenance; failures.rrd's summary adds n_failures and sources.
    """
    out = []
    for file in recording_files(path):
        reader = open_rrd(file)
        out.extend(properties(reader, entry) for entry in reader.recordings())
    return out


def read_rrd_stamp(path: str | os.PathLike[str]) -> dict[str, Any] | None:
    """The file's provenance stamp: the `provenance` property of its first recording.

    For a folder of recordings, the stamp of its `recordings.json` (the same as every
    recording's in it; a folder from before that file existed: its first file's). None when
    there is no recording or the first recording has no stamp.
    """
    path = Path(path)
    if path.is_dir() and (path / RECORDING_FOLDER_STAMP).is_file():
        return read_stamp(path / RECORDING_FOLDER_STAMP)
    files = recording_files(path)
    if not files:
        return None
    reader = open_rrd(files[0])
    entries = reader.recordings()
    if not entries:
        return None
    raw = raw_properties(reader, entries[0])
    return parse_json_property(raw.get(PROVENANCE_PROPERTY), f"{path}: provenance")


def is_mesh_store(entry: StoreEntry) -> bool:
    """A mesh store (`write.MeshStore`): meshes that episodes' recordings name, no episode."""
    return entry.recording_id.startswith(MESH_STORE_PREFIX)


def mesh_reference(reader: RrdReader, entry: StoreEntry) -> dict[str, str] | None:
    """{"recording": id, "file": name} of the mesh store a recording names, or None (its
    meshes, if any, are its own)."""
    fields = raw_properties(reader, entry).get(MESHES_PROPERTY)
    if not fields:
        return None
    return {"recording": str(fields["recording"]), "file": str(fields["file"])}


def find_mesh_store(
    reader: RrdReader, path: Path, reference: Mapping[str, str]
) -> tuple[RrdReader, StoreEntry]:
    """The mesh store a recording of `path` names: in the same file (``failures.rrd``), else
    the file it names in the same folder (a condition's folder)."""
    wanted = reference["recording"]
    for entry in reader.recordings():
        if entry.recording_id == wanted:
            return reader, entry
    other = path.parent / Path(reference["file"]).name
    if other.is_file():
        store_reader = open_rrd(other)
        for entry in store_reader.recordings():
            if entry.recording_id == wanted:
                return store_reader, entry
    raise FileNotFoundError(
        f"{path}: its meshes are in mesh store {wanted!r}, which is neither in the file nor in "
        f"{other} (copy that file beside it, or open the episode with its folder)"
        f"{rebuild_hint(other)}"
    )


def recording_chunks(reader: RrdReader, entry: StoreEntry, path: Path) -> list[Chunk]:
    """A recording's chunks with its meshes: those of the mesh store it names (if any) added
    (static, on the same entities): the recording as if it held its meshes itself."""
    own = list(reader.store(store=entry).stream())
    reference = mesh_reference(reader, entry)
    if reference is None:
        return own
    store_reader, store_entry = find_mesh_store(reader, path, reference)
    meshes = store_reader.store(store=store_entry).stream().drop(content=f"{PROPERTIES}/**")
    return own + [c for c in meshes if c.entity_path != PROPERTIES]


def episode_entries(reader: RrdReader) -> list[StoreEntry]:
    """A file's episodes' recordings: its recordings but a mesh store and a summary (the
    first recording of failures.rrd and closest_calls.rrd). What a message counts."""
    return [
        e
        for e in reader.recordings()
        if not is_mesh_store(e) and e.recording_id not in (FAILURES_SUMMARY, CLOSEST_CALLS_SUMMARY)
    ]


def _episodes(n: int) -> str:
    return f"{n} episode's recording" if n == 1 else f"{n} episodes' recordings"


def find_episode_entry(reader: RrdReader, path: Path, condition: str, state_id: int) -> StoreEntry:
    """The recording of one episode in an open file (its own, or its copy in failures.rrd)."""
    rid = episode_recording_id(condition, state_id)
    wanted = (rid, FAILURE_PREFIX + rid)
    entries = episode_entries(reader)
    for entry in entries:
        if entry.recording_id in wanted:
            return entry
    raise KeyError(
        f"{path}: no recording of condition {condition!r}, state {state_id} "
        f"(recording id {rid!r}) among its {_episodes(len(entries))}"
    )


def _column_values(values: pa.Array, instances: int, what: str) -> np.ndarray:
    """A list<...> column with `instances` values per row, as an (n, instances * k) array."""
    lengths = pc.list_value_length(values).to_numpy(zero_copy_only=False)
    if not np.all(lengths == instances):
        raise ValueError(f"{what}: expected {instances} instance(s) per row")
    flat = values.flatten()
    if pa.types.is_fixed_size_list(flat.type):
        flat = flat.flatten()
    return flat.to_numpy(zero_copy_only=False).astype(np.float64).reshape(len(values), -1)


def recorded_signals(reader: RrdReader, entry: StoreEntry) -> dict[str, list[str]]:
    """{entity (no leading slash): series names} of a recording, from its static SeriesLines."""
    out: dict[str, list[str]] = {}
    stream = reader.store(store=entry).stream().filter(is_static=True, components=SERIES_NAMES)
    for chunk in stream:
        values = column(chunk.to_record_batch(), SERIES_NAMES)
        names = values[len(values) - 1].as_py()  # static: the last row wins
        if names:
            out[chunk.entity_path.lstrip("/")] = names
    return out


def find_episode_file(
    folder: str | os.PathLike[str] | Sequence[Path], *, condition: str, state_id: int
) -> Path:
    """The file of one episode's recording in a condition's folder, in whichever shard, or in
    one of a list of shard folders (a run's own: a folder an earlier run left is not read).

    Raises:
      KeyError: no shard of the folder holds it (say, `recording.episodes` is `failed` and the
        episode succeeded).
    """
    name = episode_file_name(condition, state_id)
    if isinstance(folder, (str, os.PathLike)):
        folder = Path(folder)
        found = sorted(folder.glob(f"shard-*/{name}")) or sorted(folder.glob(name))
    else:
        found = [Path(f) / name for f in folder if (Path(f) / name).is_file()]
    if not found:
        raise KeyError(
            f"{folder}: no recording of condition {condition!r}, state {state_id} (no file "
            f"{name} in any shard; with recording.episodes: failed, only failures are recorded)"
        )
    return found[0]


def only_episode_entry(reader: RrdReader, path: Path) -> StoreEntry:
    """The one episode's recording of a file that holds one (a condition folder's file, a
    replay's), besides any mesh store."""
    entries = episode_entries(reader)
    if len(entries) != 1:
        raise ValueError(
            f"{path}: holds {_episodes(len(entries))}, expected one; give condition and "
            "state_id to pick one"
        )
    return entries[0]


def read_episode(
    path: str | os.PathLike[str], *, condition: str | None = None, state_id: int | None = None
) -> dict[str, np.ndarray]:
    """One episode's logged series, in time order.

    Returns arrays over the n logged steps: time (n,) simulated seconds (rerun keeps integer
    nanoseconds, so this is physics time rounded to 1 ns); step (n,) the physics step index;
    every series the task logs, by name (n,), exactly as logged (float64); and, for each moving
    body, `<body>_position` (n, 3) and, when it turns, `<body>_quat_wxyz` (n, 4): its pose in
    its parent body (float32 precision: rerun stores transforms as float32).

    `path` is a .rrd file or a condition's folder of recordings (`write_condition_recordings`).
    A file that holds one episode's recording alone needs no `condition` and `state_id`.

    Raises:
      KeyError: the file has no recording of that condition and state.
    """
    path = Path(path)
    if (condition is None) != (state_id is None):
        raise ValueError(f"{path}: give both condition and state_id, or neither")
    if path.is_dir():
        if condition is None or state_id is None:
            raise ValueError(f"{path}: a folder: give condition and state_id")
        path = find_episode_file(path, condition=condition, state_id=state_id)
    reader = open_rrd(path)
    if condition is None or state_id is None:
        entry = only_episode_entry(reader, path)
    else:
        entry = find_episode_entry(reader, path, condition, state_id)
    signals = recorded_signals(reader, entry)
    if not signals:
        raise ValueError(f"{path}: recording {entry.recording_id!r} has no series")
    where = {name: (e, i) for e, names in signals.items() for i, name in enumerate(names)}
    wanted: dict[str, list[tuple[str, int]]] = {
        e: [(SCALARS, len(names))] for e, names in signals.items()
    }
    store = reader.store(store=entry)
    posed: dict[str, list[str]] = {}  # entity -> its pose's components logged per step
    for chunk in store.stream().filter(has_timeline=TIMELINE):
        names = chunk.to_record_batch().schema.names
        found = [c for c in (TRANSLATION, QUATERNION) if c in names]
        if found:
            posed.setdefault(chunk.entity_path.lstrip("/"), found)
    for entity in sorted(posed):
        wanted.setdefault(entity, []).extend((c, 1) for c in posed[entity])
    parts: dict[str, list[dict[str, np.ndarray]]] = {e: [] for e in wanted}
    stream = store.stream().filter(content=[f"/{e}" for e in wanted], has_timeline=TIMELINE)
    for chunk in stream:
        entity = chunk.entity_path.lstrip("/")
        batch = chunk.to_record_batch()
        part = {"time_ns": column(batch, TIMELINE).cast(pa.int64()).to_numpy()}
        for component, width in wanted[entity]:
            if component in batch.schema.names:
                values = column(batch, component)
                part[component] = _column_values(values, width, f"{entity} {component}")
        parts[entity].append(part)

    series: dict[str, dict[str, np.ndarray]] = {}
    for entity, pieces in parts.items():
        keys = {k for c in pieces for k in c}
        missing = [c for c, _ in wanted[entity] if c not in keys]
        if not pieces or missing or any(set(c) != keys for c in pieces):
            raise ValueError(
                f"{path}: recording {entry.recording_id!r}: incomplete data at {entity}"
            )
        merged = {k: np.concatenate([c[k] for c in pieces]) for k in keys}
        order = np.argsort(merged["time_ns"], kind="stable")  # ties keep the logged order
        series[entity] = {k: v[order] for k, v in merged.items()}
    first = next(iter(series))
    time_ns = series[first]["time_ns"]
    for entity, s in series.items():
        if not np.array_equal(s["time_ns"], time_ns):
            raise ValueError(f"{path}: {entity} is not logged at the same times as {first}")

    props = _episode_property(raw_properties(reader, entry).get(EPISODE_PROPERTY, {}))
    if "n_steps" not in props or "log_every" not in props:
        raise ValueError(f"{path}: recording {entry.recording_id!r} lacks n_steps / log_every")
    steps = logged_steps(int(props["n_steps"]), int(props["log_every"]))
    if len(steps) != len(time_ns):
        raise ValueError(
            f"{path}: {len(time_ns)} rows, but n_steps and log_every give {len(steps)}"
        )

    out = {"time": time_ns / 1e9, "step": steps}
    for name, (entity, index) in where.items():
        out[name] = series[entity][SCALARS][:, index]
    for entity in sorted(posed):
        body = entity.rsplit("/", 1)[-1]
        if TRANSLATION in posed[entity]:
            out[f"{body}_position"] = series[entity][TRANSLATION]
        if QUATERNION in posed[entity]:
            out[f"{body}_quat_wxyz"] = rerun_to_mujoco_quat(series[entity][QUATERNION])
    return out
