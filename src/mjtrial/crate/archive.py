"""`mjtrial crate --zip`: a results folder, its crate and its sources in one archive.

The archive is a checkout and a crate at once: the copy of the sources the crate job made
(`source/`) at its top (Snakefile, workflow/, src/, config/, models/, tasks/, profiles/,
pyproject.toml, README.md), the run's files of the results folder under its own path
(`results/<experiment>/`: the sealed outputs, the seals, its own crate and copy), and at the
top a crate of the archive: the folder's crate with the results under `results/<experiment>/`
and the sources at the top. Unzipped anywhere, `mjtrial verify` checks it and, once installed
there, `snakemake -c2 -n` has nothing to do. What else the folder holds (the jobs' logs, a
file no job wrote) stays out, and is named (`folder_members`).

Before anything is written the folder's crate is rebuilt from the folder and compared (as
`mjtrial verify` does), and a symbolic link leaving the repository stops it; while the archive
is written each packed file is hashed and compared with the sha256 its seal records (a
source's: the crate's). Any difference stops with one line and leaves no archive.
"""

from __future__ import annotations

import hashlib
import json
import os
import zipfile
from dataclasses import dataclass
from pathlib import Path

from mjtrial import provenance
from mjtrial.crate.check import covered_seals, crate_differences, listed_sources, recorded_times
from mjtrial.crate.graph import Ids, crate_metadata
from mjtrial.crate.record import read_record
from mjtrial.crate.sources import stage_scripts
from mjtrial.crate.stamp import graph_entities, read_crate_stamp
from mjtrial.files.atomic import atomic_path
from mjtrial.files.layout import CRATE_FILE, Layout

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
    left_out: list[str]  # the folder's files it does not hold (`folder_members`)


@dataclass(frozen=True)
class Members:
    """The results folder's files split into what an archive holds and what it leaves out."""

    packed: list[Path]  # the run's files, in the order they were written
    left_out: list[str]  # every other file, relative to the folder (logs, strays)


def _run_files(layout: Layout, *, repo_root: Path) -> tuple[set[str], set[str]]:
    """The run's files and folders in the results folder (relative to it): the crate, its copy
    of the sources, the seals its stamp records and every output they list."""
    stamp = read_crate_stamp(layout.crate)
    if stamp is None:
        raise ArchiveError(f"{layout.crate}: it carries no stamp; `mjtrial verify` says why")
    prefix = provenance.repo_relative(layout.root, repo_root).rstrip("/") + "/"
    files, folders = {CRATE_FILE}, {layout.source.name}
    for seal in covered_seals(stamp):
        try:
            sealed = json.loads((repo_root / seal).read_text(encoding="utf-8"))
            listed = sealed["outputs"]
            registered = [sealed["registration"]["path"]] if "registration" in sealed else []
            if registered and layout.deviations.exists():  # noted beside it, by no job
                registered.append(prefix + layout.deviations.name)
        except (OSError, ValueError, KeyError, TypeError) as err:
            raise ArchiveError(f"{repo_root / seal}: not a readable seal ({err})") from err
        for path in [seal, *listed, *registered]:
            rel = path.removeprefix(prefix)
            (folders if (layout.root / rel).is_dir() else files).add(rel)
    return files, folders


def folder_members(layout: Layout, *, repo_root: Path) -> Members:
    """What `mjtrial crate --zip` packs of the results folder: the files the crate lists (the
    sealed outputs, the seals, the crate, `source/`) with Snakemake's `.snakemake_timestamp`
    of each folder output (the time it reads for the folder), in the order they were written:
    unzipped by a tool that does not restore times, each output is still newer than what it
    was made from, and Snakemake reruns nothing. Every other file (the jobs' logs, a file no
    job wrote) is left out, and named: the archive holds what the crate describes. Hidden
    files (the snapshot, temporaries) are neither. A symbolic link that leaves the repository
    anywhere in the folder is an ArchiveError: no job writes one."""
    repo = Path(repo_root).resolve()
    files, folders = _run_files(layout, repo_root=Path(repo_root))
    packed, left_out = [], []
    for top, dirs, names in os.walk(layout.root):
        for name in sorted(dirs + names):
            path = Path(top) / name
            if path.is_symlink() and not path.resolve().is_relative_to(repo):
                raise ArchiveError(
                    f"{path}: a symbolic link to {path.resolve()}, outside {repo}; an archive "
                    "holds the run's own files: remove it"
                )
            if name in dirs:
                continue
            rel = path.relative_to(layout.root)
            hidden = [part for part in rel.parts if part.startswith(".")]
            in_folder = any(rel.is_relative_to(f) for f in folders)
            if hidden and not (hidden == [_SNAKEMAKE_TIMESTAMP] == [name] and in_folder):
                continue
            (packed if rel.as_posix() in files or in_folder else left_out).append(path)
    packed.sort(key=lambda p: (p.stat().st_mtime_ns, p.as_posix()))
    return Members(packed, sorted(p.relative_to(layout.root).as_posix() for p in left_out))


def left_out_summary(layout: Layout, left_out: list[str]) -> str:
    """The files of the results folder that are not the run's, in a few words ("" for none):
    the jobs' logs counted, other files named (the first three)."""
    logs = layout.logs_dir.relative_to(layout.root).as_posix() + "/"
    strays = [p for p in left_out if not p.startswith(logs)]
    parts = []
    if len(strays) < len(left_out):
        parts.append(f"{len(left_out) - len(strays)} job logs ({logs})")
    if strays:
        more = f" and {len(strays) - 3} more" if len(strays) > 3 else ""
        files = "a file" if len(strays) == 1 else f"{len(strays)} files"
        parts.append(f"{files} no seal lists ({', '.join(strays[:3])}{more})")
    return " and ".join(parts)


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
    folder the pipeline ran in): its sources at the top and the run's files of the folder
    (`folder_members`). Raises ArchiveError, leaving no archive, when the crate is missing or
    does not describe the folder as it is, the folder holds a symbolic link leaving the
    repository, or a file's bytes are not what its seal (a source's: the crate) records."""
    layout = Layout(Path(results_dir))
    repo_root = Path(repo_root)
    differs = check_crate(layout, repo_root=repo_root)
    if differs:
        path, why = next(iter(differs.items()))
        raise ArchiveError(
            f"{path} does not describe the folder as it is ({why}); `mjtrial verify` says why"
        )
    members = folder_members(layout, repo_root=repo_root)
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
    # What each packed file must be: a sealed output as its seal records it, a seal as the
    # crate's stamp does, a source as the crate lists it.
    expected = {p.removeprefix(prefix): o.sha256 for p, o in record.outputs.items()}
    if record.registration is not None:
        expected[record.registration.path.removeprefix(prefix)] = record.registration.sha256
    sources = {rel: sha for rel, (sha, _) in listed_sources(entities).items()}
    expected |= {f"{layout.source.name}/{rel}": sha for rel, sha in sources.items()}
    Path(output).parent.mkdir(parents=True, exist_ok=True)
    files = 0
    with atomic_path(output) as tmp, zipfile.ZipFile(tmp, "w", allowZip64=True) as archive:
        digests: dict[str, str] = {}
        folders: set[str] = set()
        for rel in record.sources:
            digest = _add(archive, layout.source / rel, rel, folders, date_time=_SOURCE_TIME)
            _check(layout.source / rel, digest, sources.get(rel))
            files += 1
        for file in members.packed:
            rel = file.relative_to(layout.root).as_posix()
            digest = _add(archive, file, prefix + rel, folders)
            if file.name != _SNAKEMAKE_TIMESTAMP and rel != CRATE_FILE:
                digests[rel] = digest
                if rel in expected:
                    _check(file, digest, expected[rel])
            files += 1
        _check_folders(expected, digests, layout)
        info = zipfile.ZipInfo.from_file(layout.crate, CRATE_FILE)  # the folder crate's time
        info.compress_type = zipfile.ZIP_DEFLATED
        archive.writestr(info, json.dumps(top, indent=2, ensure_ascii=False) + "\n")
        files += 1
    return Archive(Path(output), files, Path(output).stat().st_size, members.left_out)


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


def _check(file: Path, got: str | None, sha: str | None) -> None:
    """A packed file's (or folder's) sha256 against what the seal or the crate records."""
    if got != sha:
        what = "missing" if got is None else "not the file the crate lists (sha256 differs)"
        raise ArchiveError(f"{file}: {what}; `mjtrial verify` says what changed")


def _check_folders(expected: dict[str, str], digests: dict[str, str], layout: Layout) -> None:
    """Each sealed folder output against the files just archived (its sha256 is mjtrial's
    digest of its files: `provenance.file_sha256`), and every file expected was archived."""
    for identifier, sha in expected.items():
        if (layout.root / identifier).is_dir():
            inside = [rel for rel in digests if rel.startswith(identifier + "/")]
            h = hashlib.sha256()
            # In the order `provenance.file_sha256` takes a folder's files: by path parts.
            for rel in sorted(inside, key=Path):
                h.update(f"{rel.removeprefix(identifier + '/')}\0{digests[rel]}\n".encode())
            _check(layout.root / identifier, h.hexdigest(), sha)
        else:
            _check(layout.root / identifier, digests.get(identifier), sha)
