"""Chosen episodes gathered in one file: ``failures.rrd`` (the failed episodes of every
condition) and ``closest_calls.rrd`` (episodes re-simulated to be watched, see
`mjtrial.closest_calls`)."""

from __future__ import annotations

import json
import os
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import rerun as rr
from rerun.chunk import Chunk, RrdReader, StoreEntry

from mjtrial.files.atomic import atomic_path
from mjtrial.provenance import RECORDING_FOLDER_STAMP
from mjtrial.recording.arrow import archetype_columns, chunks, strict
from mjtrial.recording.names import (
    APPLICATION_ID,
    FAILURE_PREFIX,
    FAILURES_PROPERTY,
    FAILURES_SUMMARY,
    JSON_FIELD,
    PROPERTIES,
    PROVENANCE_PROPERTY,
    SOURCE_PROVENANCE_PROPERTY,
    default_blueprint,
)
from mjtrial.recording.read import (
    find_episode_entry,
    find_mesh_store,
    mesh_reference,
    only_episode_entry,
    open_rrd,
    properties,
    recorded_signals,
    recording_chunks,
    recording_files,
)
from mjtrial.recording.route import rrd_output, write_recording, write_store
from mjtrial.recording.write import EpisodeRecord, EpisodeStores, stamp_json


def _static_chunk(entity: str, archetypes: list[Any]) -> Chunk:
    """One static row holding all components of `archetypes`, as `rec.log(static=True)` would."""
    return chunks(archetype_columns(entity, archetypes))[0]


def _property_chunk(name: str, fields: Mapping[str, Any]) -> Chunk:
    """What `rr.send_property(name, rr.AnyValues(**fields))` logs."""
    # One-element lists: rerun converts bare Python scalars ~10x slower (exception paths).
    values = {k: v if isinstance(v, list) else [v] for k, v in fields.items()}
    with strict():
        return Chunk.from_property(name, rr.AnyValues(**values))


class _MeshStores:
    """Copies each mesh store that the copied recordings name into the output, once, before
    the first recording that names it: a copy keeps its `meshes` property, which finds the
    store in the same file (`read.find_mesh_store`)."""

    def __init__(self, out: Any, application_id: str) -> None:
        self.out, self.application_id = out, application_id
        self.written: set[str] = set()

    def before(self, reader: RrdReader, entry: StoreEntry, path: Path) -> None:
        reference = mesh_reference(reader, entry)
        if reference is None or reference["recording"] in self.written:
            return
        store_reader, store_entry = find_mesh_store(reader, path, reference)
        chunks = list(store_reader.store(store=store_entry).stream())
        write_recording(
            self.out,
            chunks,
            application_id=self.application_id,
            recording_id=reference["recording"],
        )
        self.written.add(reference["recording"])


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
    `source_provenance`. Memory holds one recording at a time. A mesh store that copies name
    (`write.MeshStore`, a model's meshes) is copied once, before the first of them.

    Returns:
      the number of failed episodes written.
    """
    path = Path(path)
    stamp_text = stamp_json(stamp)
    readers: dict[Path, RrdReader] = {}
    failures: list[tuple[Path, StoreEntry, dict[str, Any]]] = []
    files = [f for source in sources for f in recording_files(source)]
    for source in files:
        reader = open_rrd(source)
        for entry in reader.recordings():
            props = properties(reader, entry)
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

    blueprint = default_blueprint(_plots(sources, files, readers))
    with atomic_path(path) as tmp, rrd_output(tmp, application_id, blueprint) as out:
        names = [Path(s).name for s in sources]  # names only: no private paths in outputs
        title = f"failures: {len(failures)} episode(s) from {len(names)} file(s)"
        summary = [
            _static_chunk(PROPERTIES, [rr.archetypes.RecordingInfo(name=title)]),
            _property_chunk(PROVENANCE_PROPERTY, {JSON_FIELD: stamp_text}),
            _property_chunk(
                FAILURES_PROPERTY, {"n_failures": len(failures), "sources": json.dumps(names)}
            ),
            _static_chunk(FAILURES_SUMMARY, [_failures_table(failures)]),
        ]
        write_recording(out, summary, application_id=application_id, recording_id=FAILURES_SUMMARY)
        replaced = [
            f"{PROPERTIES}/{PROVENANCE_PROPERTY}",
            f"{PROPERTIES}/{SOURCE_PROVENANCE_PROPERTY}",
        ]
        meshes = _MeshStores(out, application_id)
        for source, entry, props in failures:
            meshes.before(readers[source], entry, source)
            copied = list(readers[source].store(store=entry).stream().drop(content=replaced))
            copied.append(_property_chunk(PROVENANCE_PROPERTY, {JSON_FIELD: stamp_text}))
            original = props.get(PROVENANCE_PROPERTY)
            if original is not None:
                fields = {JSON_FIELD: json.dumps(original, allow_nan=False)}
                copied.append(_property_chunk(SOURCE_PROVENANCE_PROPERTY, fields))
            rid = FAILURE_PREFIX + entry.recording_id
            write_recording(out, copied, application_id=application_id, recording_id=rid)
    return len(failures)


def write_episodes_rrd(
    path: str | os.PathLike[str],
    groups: Sequence[tuple[EpisodeStores, Sequence[EpisodeRecord]]],
    *,
    summary_id: str,
    prefix: str,
    title: str,
    table: str,
    stamp: Mapping[str, Any],
    application_id: str = APPLICATION_ID,
) -> int:
    """Atomically write episodes of several conditions (each group: the `EpisodeStores` of its
    condition, model and stamp, and its episodes) into one file, after a summary recording (id
    `summary_id`: `title`, the `stamp`, and `table`, markdown); each episode's recording id is
    `prefix` and its id in its condition (the prefix sorts them after the summary, whose stamp
    is the file's). The viewer's layout holds every group's plots. A builder made with
    `share_meshes` has its mesh store written once, before its episodes. Returns the number of
    episodes written."""
    plots: dict[str, list[str]] = {}
    for builder, _ in groups:
        for name, entities in builder.plots:
            plots.setdefault(name, [])
            plots[name] += [e for e in entities if e not in plots[name]]
    count = 0
    with (
        atomic_path(Path(path)) as tmp,
        rrd_output(tmp, application_id, default_blueprint(list(plots.items()))) as out,
    ):
        summary = [
            _static_chunk(PROPERTIES, [rr.archetypes.RecordingInfo(name=title)]),
            _property_chunk(PROVENANCE_PROPERTY, {JSON_FIELD: stamp_json(stamp)}),
            _static_chunk(summary_id, [rr.TextDocument(table, media_type=rr.MediaType.MARKDOWN)]),
        ]
        write_recording(out, summary, application_id=application_id, recording_id=summary_id)
        stores: set[str] = set()
        for builder, episodes in groups:
            meshes = builder.meshes  # built with share_meshes: its store goes in once
            if meshes is not None and meshes.recording_id not in stores:
                write_recording(
                    out,
                    meshes.chunks(),
                    application_id=application_id,
                    recording_id=meshes.recording_id,
                )
                stores.add(meshes.recording_id)
            for group in builder.groups(episodes):
                for recording_id, store in builder.build(group):
                    write_store(
                        out,
                        store,
                        application_id=application_id,
                        recording_id=prefix + recording_id,
                    )
                    count += 1
    return count


def write_episode_copies_rrd(
    path: str | os.PathLike[str],
    episodes: Sequence[tuple[str, Path, str, int]],
    *,
    summary_id: str,
    title: str,
    table: str,
    stamp: Mapping[str, Any],
    application_id: str = APPLICATION_ID,
) -> int:
    """Atomically copy episodes' recordings, chunk for chunk, into one file after a summary
    recording (id `summary_id`: `title`, the `stamp`, `table` as markdown). Each episode is
    (label, .rrd file, condition, state id): its copy's recording id and name start with the
    label, so copies of one episode from several runs open side by side. As in
    `write_failures_rrd`, each copy's `provenance` becomes `stamp` and its own is kept as
    `source_provenance`. Returns the number of episodes written."""
    readers = {file: open_rrd(file) for _, file, _, _ in episodes}
    sources = sorted({file.parent for file in readers})
    blueprint = default_blueprint(_plots(sources, list(readers), readers))
    stamp_text = stamp_json(stamp)
    replaced = [f"{PROPERTIES}/{PROVENANCE_PROPERTY}", f"{PROPERTIES}/{SOURCE_PROVENANCE_PROPERTY}"]
    with atomic_path(Path(path)) as tmp, rrd_output(tmp, application_id, blueprint) as out:
        summary = [
            _static_chunk(PROPERTIES, [rr.archetypes.RecordingInfo(name=title)]),
            _property_chunk(PROVENANCE_PROPERTY, {JSON_FIELD: stamp_text}),
            _static_chunk(summary_id, [rr.TextDocument(table, media_type=rr.MediaType.MARKDOWN)]),
        ]
        write_recording(out, summary, application_id=application_id, recording_id=summary_id)
        meshes = _MeshStores(out, application_id)
        for label, file, condition, state_id in episodes:
            reader = readers[file]
            entry = find_episode_entry(reader, file, condition, state_id)
            meshes.before(reader, entry, file)
            props = properties(reader, entry)
            copied = list(reader.store(store=entry).stream().drop(content=replaced))
            name = f"{label}: {props.get('name') or entry.recording_id}"
            copied.append(_static_chunk(PROPERTIES, [rr.archetypes.RecordingInfo(name=name)]))
            copied.append(_property_chunk(PROVENANCE_PROPERTY, {JSON_FIELD: stamp_text}))
            if (original := props.get(PROVENANCE_PROPERTY)) is not None:
                fields = {JSON_FIELD: json.dumps(original, allow_nan=False)}
                copied.append(_property_chunk(SOURCE_PROVENANCE_PROPERTY, fields))
            rid = f"{label}-{entry.recording_id}"
            write_recording(out, copied, application_id=application_id, recording_id=rid)
    return len(episodes)


def _plots(
    sources: Sequence[str | os.PathLike[str]], files: Sequence[Path], readers: Mapping[Path, Any]
) -> list[tuple[str, list[str]]]:
    """The plots of the sources' recordings (all recorded alike): as their folder's stamp
    names them, else one plot per entity that holds series."""
    for source in sources:
        stamp = Path(source) / RECORDING_FOLDER_STAMP
        if stamp.is_file():
            plots = json.loads(stamp.read_text()).get("plots")
            if plots:
                return [(title, list(entities)) for title, entities in plots]
    for source in files[:1]:
        reader = readers.get(source) or open_rrd(source)
        if recordings := reader.recordings():
            signals = recorded_signals(reader, recordings[0])
            return [(", ".join(names), [entity]) for entity, names in signals.items()]
    return []


def _recorded_measures(props: Mapping[str, Any]) -> list[str]:
    """The measures an episode's recording keeps: its fields between success and the failure
    category (`write.episode_field`)."""
    keys = list(props)
    if "success" not in keys or "failure_category" not in keys:
        return []
    return keys[keys.index("success") + 1 : keys.index("failure_category")]


def _failures_table(failures: Sequence[tuple[Path, Any, Mapping[str, Any]]]) -> rr.TextDocument:
    measures = _recorded_measures(failures[0][2]) if failures else []
    lines = [
        "| source | condition | state | failure |" + "".join(f" {m} |" for m in measures),
        "|---|---|---|---|" + "---|" * len(measures),
    ]
    for source, _, p in failures:
        lines.append(
            f"| {source.name} | {p.get('condition')} | {p.get('state_id')} "
            f"| {p.get('failure_category') or '-'} |"
            + "".join(f" {p.get(m, float('nan')):.4f} |" for m in measures)
        )
    if not failures:
        lines.append("| - | - | - | - |")
    return rr.TextDocument("\n".join(lines), media_type=rr.MediaType.MARKDOWN)


def write_whole_episode(
    path: str | os.PathLike[str],
    output: str | os.PathLike[str],
    *,
    condition: str | None = None,
    state_id: int | None = None,
    application_id: str = APPLICATION_ID,
) -> str:
    """Atomically write one episode's recording with its meshes in it (`read.recording_chunks`)
    and its layout to `output`: a file the viewer opens alone and shows the robot in. `path` is
    the episode's file (a condition folder's, whose mesh store sits beside it) or, with
    `condition` and `state_id`, a file holding several (``failures.rrd``). Returns its
    recording id."""
    path = Path(path)
    reader = open_rrd(path)
    if condition is None or state_id is None:
        entry = only_episode_entry(reader, path)
    else:
        entry = find_episode_entry(reader, path, condition, state_id)
    blueprint = default_blueprint(_plots([path.parent], [path], {path: reader}))
    whole = recording_chunks(reader, entry, path)
    with atomic_path(Path(output)) as tmp, rrd_output(tmp, application_id, blueprint) as out:
        write_recording(out, whole, application_id=application_id, recording_id=entry.recording_id)
    return entry.recording_id
