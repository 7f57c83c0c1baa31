"""What a crate describes, read from a results folder: its seals, the stamps of every sealed
output, the outputs' sizes, the copy of the sources and the jobs' times.

Everything but the times is read from the results folder itself, so `mjtrial verify` rebuilds
the same record on any machine the folder is copied to. The times are Snakemake's record of
each job (`.snakemake/metadata/`, outside the results, kept in step with the outputs by
`mjtrial.files.safekeeping`): the crate job reads them when it writes the crate, and verify takes
them from the crate and checks them against the stamps (`time_problems`).
"""

from __future__ import annotations

import json
from collections.abc import Iterable, Mapping
from dataclasses import dataclass, field
from datetime import datetime, timezone
from pathlib import Path
from typing import Any

# recording: the reader of the .rrd stamps this stage reads is part of its code (its hash)
from mjtrial import provenance, recording  # noqa: F401
from mjtrial.crate.sources import listed_sources
from mjtrial.files.layout import Layout
from mjtrial.files.safekeeping import INCOMPLETE, METADATA, record_path

# A job's start and end as ISO 8601 UTC times with milliseconds, or None when not known.
Times = tuple[str | None, str | None]

# How far a stamp's time may lie outside its job's start and end (clocks of a cluster's nodes
# and of its shared disk differ a little; a stamp's time is whole seconds).
TIME_SLACK_S = 60.0


@dataclass(frozen=True)
class Output:
    """One sealed output: its path relative to the repository, as the seals record it."""

    path: str
    sha256: str
    folder: bool
    size: int | None  # bytes; None for a folder


@dataclass(frozen=True)
class RunRecord:
    """Everything a crate says about a results folder, read from it."""

    results: str  # the results folder, relative to the repository ("results/research_mode")
    seals: dict[str, dict[str, Any]]  # each seal the crate covers -> its stamp
    outputs: dict[str, Output]  # every output those seals list, and the seals
    stamps: dict[str, dict[str, Any]]  # every output -> its stamp
    sources: dict[str, tuple[str, int]]  # the copy of the sources: path -> (sha256, size)
    source_sha256: str
    crate_stamp: dict[str, Any]
    times: dict[str, Times] = field(default_factory=dict)  # job (its stamp's rule) -> times
    manifest: dict[str, Any] = field(default_factory=dict)
    # the registered design (`mjtrial.design.registration`), as the experiment's seal records it
    registration: Output | None = None

    def jobs(self) -> dict[str, list[str]]:
        """Each job, by its stamp's rule -> its outputs, in pipeline order of the seals."""
        jobs: dict[str, list[str]] = {}
        for path in self.outputs:
            jobs.setdefault(self.stamps[path]["rule"], []).append(path)
        return jobs


def iso_time(seconds: float) -> str:
    """A POSIX time as ISO 8601 UTC with milliseconds (`2026-11-25T07:35:12.503+00:00`)."""
    return datetime.fromtimestamp(seconds, timezone.utc).isoformat(timespec="milliseconds")


def _seconds(iso: str) -> float:
    return datetime.fromisoformat(iso.replace("Z", "+00:00")).timestamp()


def snakemake_times(workdir: Path, outputs: Mapping[str, Iterable[str]]) -> dict[str, Times]:
    """Each job's start and end from Snakemake's records of its outputs (`outputs`: job ->
    output paths as Snakemake names them): the earliest start, the latest end. A job whose
    records are missing (a results folder copied without `.snakemake/`) has no times."""
    metadata = Path(workdir) / METADATA
    times: dict[str, Times] = {}
    for job, paths in outputs.items():
        starts, ends = [], []
        for path in paths:
            try:
                record = json.loads(provenance.read_output_text(record_path(metadata, path)))
            except (OSError, ValueError):
                continue
            if isinstance(record.get("starttime"), (int, float)):
                starts.append(record["starttime"])
            if isinstance(record.get("endtime"), (int, float)):
                ends.append(record["endtime"])
        times[job] = (
            iso_time(min(starts)) if starts else None,
            iso_time(max(ends)) if ends else None,
        )
    return times


def running_job_start(workdir: Path, output: str) -> str | None:
    """When Snakemake started the job now running that writes `output` (its incomplete mark)."""
    try:
        return iso_time(record_path(Path(workdir) / INCOMPLETE, output).stat().st_mtime)
    except OSError:
        return None


def _repo_path(path: Path, repo_root: Path) -> str:
    return provenance.repo_relative(path, repo_root)


def read_record(
    layout: Layout,
    *,
    repo_root: Path,
    seals: Iterable[Path],
    crate_stamp: Mapping[str, Any],
    times: Mapping[str, Times] | None = None,
    stamps: Mapping[str, Mapping[str, Any]] | None = None,
) -> RunRecord:
    """The record of `layout`'s results folder for a crate covering `seals`.

    `stamps` are stamps already read (repository-relative path -> stamp); the others are read
    from the files. Raises `ValueError` when a seal or a sealed output cannot be read.
    """
    repo_root = Path(repo_root)
    known = dict(stamps or {})
    seal_stamps: dict[str, dict[str, Any]] = {}
    outputs: dict[str, Output] = {}
    registration: Output | None = None
    output_stamps: dict[str, dict[str, Any]] = {}
    for seal in seals:
        rel = _repo_path(seal, repo_root)
        try:
            sealed = json.loads(provenance.read_output_text(repo_root / rel))
            seal_stamps[rel] = dict(known.get(rel) or provenance.read_stamp(repo_root / rel))
            listed = sealed["outputs"]
            registered = sealed.get("registration")
            if registered is not None:  # no job's output: a file of the run all the same
                file = repo_root / registered["path"]
                registration = Output(
                    registered["path"], registered["sha256"], False, file.stat().st_size
                )
        except (OSError, ValueError, KeyError, TypeError) as err:
            raise ValueError(f"{rel}: not a readable seal ({err})") from err
        for path, sha in listed.items():
            if path in outputs:
                continue
            file = repo_root / path
            try:
                output_stamps[path] = dict(known.get(path) or provenance.read_stamp(file))
                folder = file.is_dir()
                size = None if folder else file.stat().st_size
            except (OSError, ValueError) as err:
                raise ValueError(f"{path}, sealed by {rel}: {err}") from err
            outputs[path] = Output(path, sha, folder, size)
        # The seal itself, an output of its own job, with the sha256 the crate's stamp records.
        recorded = {r["path"]: r["sha256"] for r in input_records(crate_stamp.get("inputs", {}))}
        sha = recorded.get(rel) or provenance.file_sha256(repo_root / rel)
        outputs[rel] = Output(rel, sha, False, (repo_root / rel).stat().st_size)
        output_stamps[rel] = seal_stamps[rel]
    # What the run says of itself (its question, the command that rebuilds it): an
    # experiment's manifest; a benchmark has none, and its crate's config slice says it.
    crate_slice = crate_stamp.get("config_slice") or {}
    manifest: dict[str, Any] = {k: crate_slice[k] for k in ("design", "rerun") if k in crate_slice}
    try:
        loaded = json.loads(provenance.read_output_text(layout.manifest))
        manifest = loaded if isinstance(loaded, dict) else {}
    except (OSError, ValueError):
        pass
    return RunRecord(
        results=_repo_path(layout.root, repo_root),
        seals=seal_stamps,
        outputs=outputs,
        stamps=output_stamps,
        sources=listed_sources(layout.source),
        source_sha256=provenance.file_sha256(layout.source),
        crate_stamp=dict(crate_stamp),
        times=dict(times or {}),
        manifest=manifest,
        registration=registration,
    )


def sealed_stamps(seals: Iterable[Path], *, repo_root: Path) -> dict[str, dict[str, Any]]:
    """The stamps of `seals` and of every output they list (repository-relative path ->
    stamp); what cannot be read is left out (`read_record` names it)."""
    repo_root = Path(repo_root)
    stamps: dict[str, dict[str, Any]] = {}
    for seal in seals:
        rel = _repo_path(seal, repo_root)
        try:
            listed = json.loads(provenance.read_output_text(repo_root / rel))["outputs"]
            stamps[rel] = dict(provenance.read_stamp(repo_root / rel))
        except (OSError, ValueError, KeyError, TypeError):
            continue
        for path in listed:
            if path not in stamps:
                try:
                    stamps[path] = dict(provenance.read_stamp(repo_root / path))
                except (OSError, ValueError):
                    continue
    return stamps


def read_inputs(stamps: Mapping[str, Mapping[str, Any]]) -> list[str]:
    """The files the stamped jobs read that none of them wrote (the model, the task): the
    paths their stamps record, in the order they first appear."""
    seen: dict[str, None] = {}
    for stamp in stamps.values():
        for record in input_records(stamp.get("inputs", {})):
            path = record.get("path")
            if isinstance(path, str) and path not in stamps:
                seen.setdefault(path)
    return list(seen)


def input_records(inputs: Mapping[str, Any]) -> Iterable[Mapping[str, Any]]:
    """A stamp's input records, whether an input names one file or a list."""
    for value in inputs.values():
        yield from (value if isinstance(value, list) else [value])


def time_problems(record: RunRecord) -> list[str]:
    """Jobs whose recorded times cannot hold their outputs' stamps: every stamp is made while
    its job runs, so its time lies between the job's start and end (give or take
    `TIME_SLACK_S`). What verify can check of the times on another machine."""
    problems = []
    for job, paths in record.jobs().items():
        start, end = record.times.get(job, (None, None))
        if start is not None and end is not None and _seconds(end) < _seconds(start):
            problems.append(f"{job} ends at {end}, before it starts at {start}")
        for path in paths:
            made = record.stamps[path]["created_utc"]
            if start is not None and _seconds(made) < _seconds(start) - TIME_SLACK_S:
                problems.append(f"{job} starts at {start}, after its stamp made at {made}")
            elif end is not None and _seconds(made) > _seconds(end) + 1.0 + TIME_SLACK_S:
                problems.append(f"{job} ends at {end}, before its stamp made at {made}")
    return sorted(set(problems))
