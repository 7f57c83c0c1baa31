"""`mjtrial crate --zip`: a results folder, its crate and its sources in one archive.

The archive is a checkout and a crate at once: the copy of the sources the crate job made
(`source/`) at its top (Snakefile, workflow/, src/, config/, models/, tasks/, profiles/,
pyproject.toml, README.md), the whole results folder under its own path
(`results/<experiment>/`, its own crate and copy included), and at the top a crate of the
archive: the folder's crate with the results under `results/<experiment>/` and the sources at
the top. Unzipped anywhere, `mjtrial verify` checks it and, once installed there,
`snakemake -c2 -n` has nothing to do.

Before anything is written the folder's crate is rebuilt from the folder and compared (as
`mjtrial verify` does); while the archive is written every file the crate lists is hashed and
compared with its sha256. Any difference stops with one line and leaves no archive.
"""

from __future__ import annotations

import hashlib
import json
import zipfile
from dataclasses import dataclass
from pathlib import Path

from mjtrial.atomic import atomic_path
from mjtrial.crate.check import covered_seals, crate_differences, recorded_times
from mjtrial.crate.graph import Ids, crate_metadata
from mjtrial.crate.record import read_record
from mjtrial.crate.sources import stage_scripts
from mjtrial.crate.stamp import graph_entities, read_crate_stamp
from mjtrial.layout import CRATE_FILE, Layout

# Formats that are compressed already: stored as they are.
_STORED = (".rrd", ".parquet", ".png", ".rbl")
_BLOCK = 1 << 20
_SNAKEMAKE_TIMESTAMP = ".snakemake_timestamp"
# The sources' time in the archive: older than any result, as nothing of them is a result.
_SOURCE_TIME = (1980, 1, 1, 0, 0, 0)


class ArchiveError(Exception):
    """The folder cannot be archived as it is (one line saying why)."""


@dataclass(frozen=True)
class Archive:
    """What `write_archive` wrote."""

    path: Path
    files: int
    bytes: int


def _results_files(folder: Path) -> list[Path]:
    """Every file of the results folder but hidden ones (the snapshot, temporaries), with
    Snakemake's `.snakemake_timestamp` of each folder output (the time it reads for the
    folder), in the order they were written: unzipped by a tool that does not restore times,
    each output is still newer than what it was made from, and Snakemake reruns nothing."""
    files = []
    for p in folder.rglob("*"):
        hidden = [part for part in p.relative_to(folder).parts if part.startswith(".")]
        if p.is_file() and (not hidden or hidden == [_SNAKEMAKE_TIMESTAMP] == [p.name]):
            files.append(p)
    return sorted(files, key=lambda p: (p.stat().st_mtime_ns, p.as_posix()))


def check_crate(layout: Layout, *, repo_root: Path) -> dict[str, str]:
    """Why the folder's crate (or its copy of the sources) is not what the folder gives;
    empty when it is. ArchiveError when there is no crate."""
    if not layout.crate.is_file():
        raise ArchiveError(
            f"{layout.crate}: no crate; `snakemake -c2` (or a study's target) writes it"
        )
    try:
        return crate_differences(layout, repo_root=repo_root, stamps={})
    except (OSError, ValueError) as err:
        raise ArchiveError(f"{layout.crate}: cannot be checked ({err})") from err


def write_archive(results_dir: Path, output: Path, *, repo_root: Path) -> Archive:
    """Write the zip `output` of the results folder `results_dir` (inside `repo_root`, the
    folder the pipeline ran in). Raises ArchiveError, leaving no archive, when the crate is
    missing or does not describe the folder as it is, or a file does not match the crate."""
    layout = Layout(Path(results_dir))
    repo_root = Path(repo_root)
    differs = check_crate(layout, repo_root=repo_root)
    if differs:
        path, why = next(iter(differs.items()))
        raise ArchiveError(
            f"{path} does not describe the folder as it is ({why}); `mjtrial verify` says why"
        )
    entities = graph_entities(layout.crate)
    crate_stamp = read_crate_stamp(layout.crate)
    record = read_record(
        layout,
        repo_root=repo_root,
        seals=[repo_root / p for p in covered_seals(crate_stamp)],
        crate_stamp=crate_stamp,
        times=recorded_times(entities),
    )
    prefix = record.results.rstrip("/") + "/"
    top = crate_metadata(
        record,
        ids=Ids(results=record.results, data=prefix, source=""),
        scripts=stage_scripts(layout.source),
    )
    expected = {i: e["sha256"] for i, e in entities.items() if isinstance(e.get("sha256"), str)}
    Path(output).parent.mkdir(parents=True, exist_ok=True)
    files = 0
    with atomic_path(output) as tmp, zipfile.ZipFile(tmp, "w", allowZip64=True) as archive:
        digests: dict[str, str] = {}
        folders: set[str] = set()
        for rel in record.sources:
            _add(archive, layout.source / rel, rel, folders, date_time=_SOURCE_TIME)
            files += 1
        for file in _results_files(layout.root):
            rel = file.relative_to(layout.root).as_posix()
            digest = _add(archive, file, prefix + rel, folders)
            if file.name != _SNAKEMAKE_TIMESTAMP:
                digests[rel] = digest
            files += 1
        _check_digests(expected, digests, layout)
        info = zipfile.ZipInfo.from_file(layout.crate, CRATE_FILE)  # the folder crate's time
        info.compress_type = zipfile.ZIP_DEFLATED
        archive.writestr(info, json.dumps(top, indent=2, ensure_ascii=False) + "\n")
        files += 1
    return Archive(Path(output), files, Path(output).stat().st_size)


def _add(
    archive: zipfile.ZipFile,
    file: Path,
    name: str,
    folders: set[str],
    *,
    date_time: tuple[int, int, int, int, int, int] | None = None,
) -> str:
    """Write `file` into the archive as `name` (its folders first, as entries of their own:
    a crate's `Dataset` is a folder of the archive), hashing its bytes on the way; its sha256."""
    parts = name.split("/")[:-1]
    for i in range(1, len(parts) + 1):
        folder = "/".join(parts[:i]) + "/"
        if folder not in folders:
            archive.writestr(zipfile.ZipInfo(folder, date_time=_SOURCE_TIME), b"")
            folders.add(folder)
    info = zipfile.ZipInfo.from_file(file, name)
    if date_time is not None:
        info.date_time = date_time
    stored = file.suffix.lower() in _STORED
    info.compress_type = zipfile.ZIP_STORED if stored else zipfile.ZIP_DEFLATED
    digest = hashlib.sha256()
    with open(file, "rb") as src, archive.open(info, "w", force_zip64=True) as dst:
        while block := src.read(_BLOCK):
            digest.update(block)
            dst.write(block)
    return digest.hexdigest()


def _check_digests(expected: dict[str, str], digests: dict[str, str], layout: Layout) -> None:
    """Each file and folder the crate lists against the bytes just archived (a folder's
    sha256 is mjtrial's digest of its files: `provenance.file_sha256`)."""
    folders: dict[str, list[str]] = {}
    for identifier in expected:
        if identifier.endswith("/"):
            folders[identifier] = []
    for rel in digests:
        for folder in folders:
            if rel.startswith(folder):
                folders[folder].append(rel)
    for identifier, sha in expected.items():
        if identifier.endswith("/"):
            h = hashlib.sha256()
            # In the order `provenance.file_sha256` takes a folder's files: by path parts.
            for rel in sorted(folders[identifier], key=Path):
                h.update(f"{rel.removeprefix(identifier)}\0{digests[rel]}\n".encode())
            got = h.hexdigest()
        else:
            got = digests.get(identifier)
        if got != sha:
            what = "missing" if got is None else "not the file the crate lists (sha256 differs)"
            raise ArchiveError(
                f"{layout.root / identifier}: {what}; `mjtrial verify` says what changed"
            )
