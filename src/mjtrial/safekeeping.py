"""No good result is lost: the results as they were before a run, put back where a job failed.

Snakemake deletes a job's outputs before it runs the job, and again when the job fails, so a
failure (a bug, a bad value, a full disk, an out-of-memory kill) would lose the last good
results. The Snakefile's `onstart` takes a snapshot of the results folder; `onerror` puts back
every output that the run removed and did not rebuild; `onsuccess` drops the snapshot.

The snapshot costs almost nothing: outputs are always replaced by rename, never edited in place
(`mjtrial.atomic`), so hard links keep the old bytes. Snakemake also rewrites the job's
metadata record (its params, which decide reruns) when the job starts, so the records of the
results' outputs are copied too and put back with their outputs: a restored output is then
exactly as up to date as it was, and a changed config still reruns it.

A run killed outright (SIGKILL, a power cut) runs no handler; the next run's `onstart` first
puts back what that run removed, from the snapshot it left.
"""

from __future__ import annotations

import base64
import os
import shutil
from dataclasses import dataclass
from pathlib import Path

SNAPSHOT = Path(".snakemake") / "mjtrial-snapshot"
METADATA = Path(".snakemake") / "metadata"
_FILES = "files"
_RECORDS = "records"


def _hidden(rel: Path) -> bool:
    return any(part.startswith(".") for part in rel.parts)


def _record_subject(record: Path, metadata: Path) -> Path | None:
    """The output path a Snakemake metadata record is about (its name is the path in urlsafe
    base64, split into parts of the file-name length, all but the last prefixed with "@")."""
    parts = record.relative_to(metadata).parts
    encoded = "".join(p.removeprefix("@") for p in parts)
    try:
        return Path(base64.urlsafe_b64decode(encoded.encode()).decode())
    except (ValueError, UnicodeDecodeError):
        return None


def _link_or_copy(src: Path, dst: Path) -> None:
    dst.parent.mkdir(parents=True, exist_ok=True)
    try:
        os.link(src, dst)
    except OSError:  # another filesystem, or links not allowed: a copy keeps the bytes too
        shutil.copy2(src, dst)


@dataclass(frozen=True)
class Snapshot:
    """The snapshot of one results folder, kept under `workdir/.snakemake/mjtrial-snapshot/`.

    `results` and `logs` are relative to `workdir` (Snakemake's working directory, absolute),
    as Snakemake records output paths.
    """

    results: Path
    logs: Path  # the logs folder: a failed run's logs are the news, never replaced
    workdir: Path = Path(".")

    @property
    def folder(self) -> Path:
        return self.workdir / SNAPSHOT

    def _outputs(self, metadata: Path) -> dict[Path, list[Path]]:
        """Outputs under the results folder that Snakemake has a record of: path -> records."""
        found: dict[Path, list[Path]] = {}
        if not metadata.is_dir():
            return found
        for record in metadata.rglob("*"):
            if not record.is_file():
                continue
            subject = _record_subject(record, metadata)
            if subject is not None and (subject == self.results or self.results in subject.parents):
                found.setdefault(subject, []).append(record)
        return found

    def take(self) -> list[Path]:
        """Put back what a killed run left removed, then snapshot the results as they are now.

        Returns the outputs put back from a previous run's snapshot (usually none).
        """
        restored = self.restore() if self.folder.exists() else []
        self.drop()
        root = self.workdir / self.results
        if root.is_dir():
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
        return restored

    def restore(self) -> list[Path]:
        """Put back every output of the snapshot that is missing now, with its metadata record.

        An output is a file, or a folder that Snakemake records as one output (the rollouts'
        recordings): a folder comes back whole, and only when it is missing whole, so a folder
        that a successful job rebuilt is never mixed with old files. Logs are not outputs and
        stay as the failed run wrote them. Returns the outputs put back, sorted.
        """
        files = self.folder / _FILES
        if not files.is_dir():
            return []
        saved_records = self.folder / _RECORDS
        records = self._outputs(saved_records)
        folders = {p for p in records if (files / p).is_dir()}
        restored: list[Path] = []
        for folder in sorted(folders):
            if not (self.workdir / folder).exists():
                shutil.copytree(files / folder, self.workdir / folder, copy_function=os.link)
                restored.append(folder)
        for saved in sorted(p for p in files.rglob("*") if p.is_file()):
            rel = saved.relative_to(files)
            if any(f == rel or f in rel.parents for f in folders) or self.logs in rel.parents:
                continue  # inside a recorded folder (handled above), or a log
            if not (self.workdir / rel).exists():
                _link_or_copy(saved, self.workdir / rel)
                restored.append(rel)
        metadata = self.workdir / METADATA
        for output in restored:
            for record in records.get(output, []):
                target = metadata / record.relative_to(saved_records)
                target.parent.mkdir(parents=True, exist_ok=True)
                shutil.copy2(record, target)
        return sorted(restored)

    def drop(self) -> None:
        shutil.rmtree(self.folder, ignore_errors=True)


def remove_stale_temporaries(results: Path) -> list[Path]:
    """Remove the hidden temporary files and folders that killed jobs left (`.name.tmp-*`)."""
    if not results.is_dir():
        return []
    stale = [p for p in results.rglob(".*.tmp-*")]
    for p in sorted(stale, reverse=True):
        if p.is_dir() and not p.is_symlink():
            shutil.rmtree(p, ignore_errors=True)
        else:
            p.unlink(missing_ok=True)
    return sorted(stale)
