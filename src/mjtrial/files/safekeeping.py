"""No good result is lost: the results as they were before a run, put back where a job failed or
the run was killed.

Snakemake deletes a job's outputs before it runs the job, and again when the job fails, so a
failure (a bug, a bad value, a full disk, an out-of-memory kill) would lose the last good
results. The Snakefile's `onstart` takes a snapshot of the results folder before any job runs;
`onerror` puts back every output that the run removed or rebuilt, so that the folder is the last
good run's (a rebuilt states table beside the old rollouts would be consistent with nothing);
`onsuccess` drops the snapshot.

The snapshot lives inside the results folder (`<results>/.snapshot/`, hidden): on the results'
own filesystem, so hard links work wherever the results are (a symlink to another disk
included), and gone with the folder when a user deletes it, so nothing is ever put back into
a folder deleted since. Outputs are always replaced by rename, never edited in place
(`mjtrial.files.atomic`), so hard links keep the old bytes at no cost; where links cannot be made,
copies are. Snakemake also rewrites a job's metadata record (its params, which decide reruns)
when the job starts, so the records of the outputs are copied too and put back with them: a
restored output is then exactly as up to date as it was.

A run killed outright (SIGKILL, a power cut) runs no handler. Whenever the workflow is next
loaded (any `snakemake` call in the main process, with or without jobs to run), a snapshot whose
run is dead is used to put back the outputs that run had started to rebuild (those Snakemake
marks incomplete) and are missing, with their records; the marks of what was put back are
cleared, and the hidden temporaries its killed jobs left are removed. A snapshot that cannot be
used is set aside (`.snapshot-broken-<time>`) and reported, never in the way of a later run.
"""

from __future__ import annotations

import base64
import json
import os
import shutil
import socket
import time
from dataclasses import dataclass
from pathlib import Path

import psutil

from mjtrial.files.atomic import temp_path_for

SNAPSHOT = ".snapshot"  # inside the results folder
METADATA = Path(".snakemake") / "metadata"
INCOMPLETE = Path(".snakemake") / "incomplete"
_FILES = "files"
_RECORDS = "records"
_OWNER = "owner.json"  # the run that took the snapshot
_COMPLETE = "complete"  # written last: a snapshot without it was never used by a job


def _hidden(rel: Path) -> bool:
    return any(part.startswith(".") for part in rel.parts)


def record_subject(record: Path, folder: Path) -> Path | None:
    """The output path a Snakemake metadata record or incomplete marker is about (its name is
    the path in urlsafe base64, split into parts of the file-name length, all but the last
    prefixed with "@")."""
    parts = record.relative_to(folder).parts
    encoded = "".join(p.removeprefix("@") for p in parts)
    try:
        return Path(base64.urlsafe_b64decode(encoded.encode()).decode())
    except (ValueError, UnicodeDecodeError):
        return None


def record_path(folder: Path, subject: str) -> Path:
    """Where Snakemake keeps its record of the output `subject` (its path as Snakemake names
    it) in `folder` (the metadata or incomplete folder): the inverse of `record_subject`."""
    max_len = os.pathconf(folder, "PC_NAME_MAX") if os.name == "posix" else 255
    max_len = max_len or 255
    encoded = base64.urlsafe_b64encode(subject.encode()).decode()
    parts = [encoded[i : i + max_len - 1] for i in range(0, len(encoded), max_len - 1)]
    return folder.joinpath(*["@" + p for p in parts[:-1]], parts[-1])


def _link_or_copy(src: Path | str, dst: Path | str) -> None:
    Path(dst).parent.mkdir(parents=True, exist_ok=True)
    try:
        os.link(src, dst)
    except OSError:  # another filesystem, or links not allowed: a copy keeps the bytes too
        shutil.copy2(src, dst)


def _this_process() -> dict[str, object]:
    me = psutil.Process()
    return {"pid": me.pid, "host": socket.gethostname(), "created": me.create_time()}


def _alive(owner: dict[str, object]) -> bool:
    """Whether the process that wrote `owner` still runs (same host, pid and start time)."""
    if owner.get("host") != socket.gethostname():
        return True  # another machine's run: never ours to judge
    try:
        return psutil.Process(int(owner["pid"])).create_time() == owner.get("created")
    except (psutil.Error, KeyError, TypeError, ValueError):
        return False


@dataclass(frozen=True)
class Recovery:
    """What the workflow's load did with a killed run's snapshot."""

    restored: tuple[Path, ...] = ()
    removed: tuple[Path, ...] = ()  # temporaries the killed run's jobs left
    set_aside: Path | None = None  # where a snapshot that could not be used was moved
    error: str = ""


@dataclass(frozen=True)
class Snapshot:
    """The snapshot of one results folder, kept in `workdir/results/.snapshot/`.

    `results` and `logs` are relative to `workdir` (Snakemake's working directory, absolute),
    as Snakemake records output paths.
    """

    results: Path
    logs: Path  # the logs folder: a failed run's logs are the news, never replaced
    workdir: Path = Path(".")

    @property
    def folder(self) -> Path:
        return self.workdir / self.results / SNAPSHOT

    def _outputs(self, records_dir: Path) -> dict[Path, list[Path]]:
        """Outputs under the results folder that `records_dir` (Snakemake's metadata or
        incomplete folder, or the snapshot's copy) has a file about: path -> those files."""
        found: dict[Path, list[Path]] = {}
        if not records_dir.is_dir():
            return found
        for record in records_dir.rglob("*"):
            if not record.is_file():
                continue
            subject = record_subject(record, records_dir)
            if subject is not None and (subject == self.results or self.results in subject.parents):
                found.setdefault(subject, []).append(record)
        return found

    def take(self) -> None:
        """Snapshot the results as they are now (any older snapshot is dropped first).

        Raises OSError when it cannot be completed (a full disk): then no job may run, and the
        partial snapshot is removed.
        """
        self.drop()
        root = self.workdir / self.results
        if not root.is_dir():
            return
        try:
            self.folder.mkdir()
            (self.folder / _OWNER).write_text(json.dumps(_this_process()))
            for path in root.rglob("*"):
                rel = path.relative_to(self.workdir)
                if (
                    path.is_file()
                    and not path.is_symlink()
                    and not _hidden(rel.relative_to(self.results))
                ):
                    _link_or_copy(path, self.folder / _FILES / rel)
            metadata = self.workdir / METADATA
            for records in self._outputs(metadata).values():
                for record in records:
                    target = self.folder / _RECORDS / record.relative_to(metadata)
                    target.parent.mkdir(parents=True, exist_ok=True)
                    shutil.copy2(record, target)  # a copy: Snakemake rewrites records in place
            (self.folder / _COMPLETE).touch()
        except OSError:
            self.drop()
            raise

    def saved(self, output: Path) -> Path | None:
        """The snapshot's copy of `output` (a path relative to the working folder, as
        Snakemake names it), when the snapshot holds one."""
        copy = self.folder / _FILES / output
        return copy if (self.folder / _COMPLETE).is_file() and copy.is_file() else None

    def restore(self, only: set[Path] | None = None, *, replaced: bool = False) -> list[Path]:
        """Put back every output of the snapshot that is missing now (of `only`, if given),
        with its metadata record; with `replaced`, also every output that a job of this run
        rebuilt (its record is not the snapshot's), so that the folder is the last good run's.

        An output is a file, or a folder that Snakemake records as one output (the rollouts'
        recordings): a folder comes back whole, never mixed with a rebuilt folder's files. Logs
        are not outputs and stay as the failed run wrote them. Returns the outputs put back,
        sorted.
        """
        files = self.folder / _FILES
        if not files.is_dir():
            return []
        saved_records = self.folder / _RECORDS
        records = self._outputs(saved_records)
        folders = {p for p in records if (files / p).is_dir()}
        metadata = self.workdir / METADATA

        def wanted(output: Path) -> bool:
            if only is not None and output not in only:
                return False
            if not (self.workdir / output).exists():
                return True
            return replaced and any(
                not (metadata / r.relative_to(saved_records)).is_file()
                or (metadata / r.relative_to(saved_records)).read_bytes() != r.read_bytes()
                for r in records.get(output, [])
            )

        restored: list[Path] = []
        for folder in sorted(folders):
            if wanted(folder):
                target = self.workdir / folder
                aside = temp_path_for(target)
                if target.exists():
                    os.replace(target, aside)
                shutil.copytree(files / folder, target, copy_function=_link_or_copy)
                shutil.rmtree(aside, ignore_errors=True)
                restored.append(folder)
        for saved in sorted(p for p in files.rglob("*") if p.is_file()):
            rel = saved.relative_to(files)
            if any(f == rel or f in rel.parents for f in folders) or self.logs in rel.parents:
                continue  # inside a recorded folder (handled above), or a log
            if wanted(rel):
                tmp = temp_path_for(self.workdir / rel)
                _link_or_copy(saved, tmp)
                os.replace(tmp, self.workdir / rel)
                restored.append(rel)
        for output in restored:
            for record in records.get(output, []):
                target = metadata / record.relative_to(saved_records)
                target.parent.mkdir(parents=True, exist_ok=True)
                shutil.copy2(record, target)
        return sorted(restored)

    def recover(self) -> Recovery | None:
        """At workflow load: use the snapshot a killed run left, if that run is dead.

        Puts back the outputs the killed run had started to rebuild (Snakemake's incomplete
        marks) that are missing now, clears their marks, removes the temporaries its killed
        jobs left, and drops the snapshot. Returns None when there is nothing to do (no
        snapshot, or its run is still alive). The temporaries go here, not only at the next
        run's start: once everything is put back the next run may have nothing to do, and
        starts nothing. No other run can have written them: the dead run still holds
        Snakemake's lock on the folder.
        """
        if not self.folder.is_dir():
            return None
        try:
            owner = json.loads((self.folder / _OWNER).read_text())
        except (OSError, ValueError):
            owner = {}
        if owner and _alive(owner):
            return None
        try:
            restored: list[Path] = []
            if (self.folder / _COMPLETE).exists():
                marks = self._outputs(self.workdir / INCOMPLETE)
                restored = self.restore(only=set(marks))
                for output in restored:
                    for mark in marks.get(output, []):
                        mark.unlink(missing_ok=True)
            self.drop()
            removed = remove_stale_temporaries(self.workdir / self.results)
            return Recovery(restored=tuple(restored), removed=tuple(removed))
        except OSError as err:
            aside = self.folder.with_name(f"{SNAPSHOT}-broken-{time.strftime('%Y%m%dT%H%M%S')}")
            try:
                self.folder.rename(aside)
            except OSError:
                shutil.rmtree(self.folder, ignore_errors=True)
                aside = None
            return Recovery(set_aside=aside, error=f"{type(err).__name__}: {err}")

    def drop(self) -> None:
        shutil.rmtree(self.folder, ignore_errors=True)


def remove_stale_temporaries(results: Path) -> list[Path]:
    """Remove the hidden temporary files and folders that killed jobs left (`.name.tmp-*`);
    returns those removed. Best effort: one that cannot be removed stays, for the next try."""
    if not results.is_dir():
        return []
    stale = [
        p
        for p in results.rglob(".*.tmp-*")
        if not p.relative_to(results).parts[0].startswith(SNAPSHOT)
    ]
    for p in sorted(stale, reverse=True):
        if p.is_dir() and not p.is_symlink():
            shutil.rmtree(p, ignore_errors=True)
        else:
            try:
                p.unlink(missing_ok=True)
            except OSError:
                pass
    return sorted(p for p in stale if not p.exists() and not p.is_symlink())
