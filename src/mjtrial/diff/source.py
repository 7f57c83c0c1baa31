"""Where a diff reads a run: a results folder, or an archive `mjtrial crate --zip` wrote.

A diff reads only what a run left on disk (its seals, stamps, manifest, summaries, tables and
recordings), never the checkout it runs in, so an archive from another machine compares as
well as a folder. An archive's results folder is unpacked into a temporary folder, less its
recordings, which are unpacked one episode at a time when the diff asks for one.
"""

from __future__ import annotations

import hashlib
import json
import os
import re
import shutil
import tempfile
import zipfile
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path, PurePosixPath
from typing import Any

from mjtrial import provenance
from mjtrial.files.layout import STUDIES, Layout

# An archive's results folder: `results/<experiment>/`, beside the sources (`crate.archive`).
_ARCHIVED_SEAL = re.compile(r"(results/[^/]+/)seal\.json")


class RunError(ValueError):
    """A path that is not a run a diff can read (one line saying why)."""


@dataclass
class Run:
    """One side of a diff: the results folder as it is on disk (an archive's, unpacked).

    `outputs` maps every sealed output, as a path relative to the results folder, to the
    sha256 its seal records.
    """

    label: str  # as the user named it
    root: Path
    outputs: dict[str, str]
    archive: zipfile.ZipFile | None = None
    prefix: str = ""  # the results folder inside the archive
    _scratch: Path | None = field(default=None, repr=False)

    @property
    def layout(self) -> Layout:
        return Layout(self.root)

    def path(self, rel: str) -> Path:
        """An output of the run by its path relative to the results folder; a recording of an
        archive is unpacked first."""
        path = self.root / rel
        if self.archive is not None and not path.exists():
            member = self.prefix + rel
            try:
                self.archive.getinfo(member)
            except KeyError:
                return path
            self.archive.extract(member, self._scratch)
        return path

    def disk_sha256(self, rel: str) -> str | None:
        """The sha256 of the output `rel` as it is now (`provenance.file_sha256`: a folder's
        from its files' names and bytes), None when it is gone: what the seal records of it
        is what the run was, not what the folder holds. An archive's outputs are hashed from
        its members (its recordings are not unpacked)."""
        path = self.root / rel
        if self.archive is None:
            return provenance.file_sha256(path) if path.exists() else None
        member = self.prefix + rel
        names = set(self.archive.namelist())
        if member in names:
            return self._member_sha256(member)
        inside = sorted(
            PurePosixPath(n[len(member) + 1 :])
            for n in names
            if n.startswith(member + "/") and not n.endswith("/")
        )
        inside = [q for q in inside if not any(part.startswith(".") for part in q.parts)]
        if not inside:
            return None
        digest = hashlib.sha256()
        for q in inside:
            digest.update(f"{q.as_posix()}\0{self._member_sha256(f'{member}/{q}')}\n".encode())
        return digest.hexdigest()

    def _member_sha256(self, member: str) -> str:
        assert self.archive is not None
        h = hashlib.sha256()
        with self.archive.open(member) as fh:
            while block := fh.read(1 << 20):
                h.update(block)
        return h.hexdigest()

    def json(self, rel: str) -> dict[str, Any] | None:
        """A JSON output, or None when the run has none there."""
        path = self.root / rel
        if not path.is_file():
            return None
        try:
            obj = json.loads(provenance.read_output_text(path))
        except ValueError as err:
            raise RunError(f"{self.label}: {rel}: not readable JSON ({err})") from err
        return obj if isinstance(obj, dict) else None

    def close(self) -> None:
        if self.archive is not None:
            self.archive.close()
        if self._scratch is not None:
            shutil.rmtree(self._scratch, ignore_errors=True)


def _seal_outputs(root: Path, label: str) -> dict[str, str]:
    """Every output the run's seals list (its experiment's and its studies'), relative to the
    results folder, with their sha256."""
    seals = [Layout(root).seal, *(Layout(root).study_seal(s) for s in STUDIES)]
    listed: dict[str, str] = {}
    for seal in seals:
        if not seal.is_file():
            continue
        try:
            outputs = json.loads(provenance.read_output_text(seal))["outputs"]
            listed.update({str(k): str(v) for k, v in outputs.items()})
        except (ValueError, KeyError, TypeError, AttributeError) as err:
            raise RunError(f"{label}: {seal.name}: not a readable seal ({err})") from err
    if not listed:
        raise RunError(f"{label}: {Layout(root).seal.name}: lists no output")
    # Seals record paths relative to the repository the run was made in: the folder's own
    # path there is what they share (every output lies in it, states.parquet at its top).
    recorded = (
        os.path.commonpath(listed) if len(listed) > 1 else os.path.dirname(next(iter(listed)))
    )
    return {Path(p).relative_to(recorded).as_posix(): s for p, s in sorted(listed.items())}


def _open_folder(path: Path, label: str) -> Run:
    if not Layout(path).seal.is_file():
        raise RunError(
            f"{label}: no {Layout(path).seal.name}: expected a sealed results folder "
            "(results/<experiment> after `snakemake -c2`) or an archive of `mjtrial crate --zip`"
        )
    return Run(label=label, root=path, outputs=_seal_outputs(path, label))


def _open_archive(path: Path, label: str) -> Run:
    archive = zipfile.ZipFile(path)
    found = [m.group(1) for n in archive.namelist() if (m := _ARCHIVED_SEAL.fullmatch(n))]
    if len(found) != 1:
        archive.close()
        what = "no results/<experiment>/seal.json" if not found else f"{len(found)} runs"
        raise RunError(f"{label}: {what}; expected an archive of `mjtrial crate --zip`")
    prefix = found[0]
    scratch = Path(tempfile.mkdtemp(prefix="mjtrial-diff-"))
    # Everything but the recordings (an .rrd per episode: gigabytes at N = 20,000).
    for name in archive.namelist():
        if name.startswith(prefix) and not name.endswith((".rrd", "/")):
            archive.extract(name, scratch)
    root = scratch / prefix
    try:
        outputs = _seal_outputs(root, label)
    except RunError:
        archive.close()
        shutil.rmtree(scratch, ignore_errors=True)
        raise
    return Run(label, root, outputs, archive=archive, prefix=prefix, _scratch=scratch)


def open_run(path: str | os.PathLike[str]) -> Run:
    """The run at `path`: a results folder, or an archive of one (`mjtrial crate --zip`).

    Raises:
      RunError: `path` is neither, or its seal cannot be read.
    """
    label = str(path)
    path = Path(path)
    if path.is_dir():
        return _open_folder(path, label)
    if path.is_file() and zipfile.is_zipfile(path):
        return _open_archive(path, label)
    if not path.exists():
        raise RunError(f"{label}: no such folder or archive")
    raise RunError(f"{label}: expected a results folder or a .zip of `mjtrial crate --zip`")


def iter_stamps(run: Run) -> Iterator[tuple[str, dict[str, Any]]]:
    """(output, stamp) of every sealed output whose stamp is readable without its recordings
    (a recordings folder's from its `recordings.json`; `failures.rrd`'s is its stage's too)."""
    for rel in run.outputs:
        path = run.root / rel
        if rel.endswith(".rrd") or not path.exists():
            continue
        try:
            yield rel, provenance.read_stamp(path)
        except (OSError, ValueError):
            continue  # `mjtrial verify` says why; a diff compares what is there
