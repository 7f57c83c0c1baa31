"""The snapshot that puts back what a failed run removed, on a hand-made results folder.

The end-to-end cases (a real failing job under Snakemake) are in test_trust.py.
"""

from __future__ import annotations

import base64
import errno
import json
import os
from pathlib import Path

import pytest

from mjtrial.files import safekeeping
from mjtrial.files.safekeeping import INCOMPLETE, METADATA, Snapshot, remove_stale_temporaries

RESULTS = Path("results/x")


def record_path(workdir: Path, output: Path, folder: Path = METADATA) -> Path:
    """Where Snakemake keeps an output's metadata record (or its incomplete mark): its path in
    urlsafe base64."""
    return workdir / folder / base64.urlsafe_b64encode(str(output).encode()).decode()


def write(path: Path, text: str) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(text)


@pytest.fixture
def workdir(tmp_path) -> Path:
    """results/x with a table, a folder of recordings, a log, and records of the outputs."""
    for rel, text in {
        "table.parquet": "old table",
        "rollouts/fast/ep-1.rrd": "old 1",
        "rollouts/fast/ep-2.rrd": "old 2",
        "logs/rollout.log": "old log",
    }.items():
        write(tmp_path / RESULTS / rel, text)
    for output in ("table.parquet", "rollouts/fast"):
        write(record_path(tmp_path, RESULTS / output), f"record of old {output}")
    return tmp_path


def snapshot(workdir: Path) -> Snapshot:
    return Snapshot(RESULTS, logs=RESULTS / "logs", workdir=workdir)


def replace(path: Path, text: str) -> None:
    """As every writer does: a new file renamed over the old one."""
    tmp = path.with_name(f".{path.name}.tmp")
    tmp.write_text(text)
    os.replace(tmp, path)


def test_a_failed_job_gets_its_outputs_and_records_back_and_nothing_else(workdir):
    snap = snapshot(workdir)
    snap.take()
    table = workdir / RESULTS / "table.parquet"
    # The failed job: Snakemake rewrote its record, then removed its output.
    record_path(workdir, RESULTS / "table.parquet").write_text("record of the failed job")
    table.unlink()
    # A job that succeeded in the same run rebuilt the recordings folder with new files.
    folder = workdir / RESULTS / "rollouts" / "fast"
    for p in folder.iterdir():
        p.unlink()
    write(folder / "ep-1.rrd", "new 1")
    record_path(workdir, RESULTS / "rollouts/fast").write_text("record of the new folder")
    replace(workdir / RESULTS / "logs" / "rollout.log", "the failed job's error")

    assert snap.restore() == [RESULTS / "table.parquet"]
    assert table.read_text() == "old table"
    assert record_path(workdir, RESULTS / "table.parquet").read_text() == (
        "record of old table.parquet"
    )
    # The rebuilt folder is not mixed with old files; the log is the failed run's.
    assert sorted(p.name for p in folder.iterdir()) == ["ep-1.rrd"]
    assert (folder / "ep-1.rrd").read_text() == "new 1"
    assert record_path(workdir, RESULTS / "rollouts/fast").read_text() == (
        "record of the new folder"
    )
    assert (workdir / RESULTS / "logs" / "rollout.log").read_text() == "the failed job's error"


def test_a_removed_folder_comes_back_whole(workdir):
    snap = snapshot(workdir)
    snap.take()
    folder = workdir / RESULTS / "rollouts" / "fast"
    for p in folder.iterdir():
        p.unlink()
    folder.rmdir()
    assert snap.restore() == [RESULTS / "rollouts" / "fast"]
    assert {p.name: p.read_text() for p in folder.iterdir()} == {
        "ep-1.rrd": "old 1",
        "ep-2.rrd": "old 2",
    }


def test_the_snapshot_keeps_old_bytes_when_the_output_is_replaced(workdir):
    snap = snapshot(workdir)
    snap.take()
    table = workdir / RESULTS / "table.parquet"
    replace(table, "new table")  # a job that succeeded
    assert snap.restore() == []
    assert table.read_text() == "new table"
    table.unlink()  # ... and a later failure in the same run removed it again
    assert snap.restore() == [RESULTS / "table.parquet"]
    assert table.read_text() == "old table"


def test_with_replaced_what_a_job_of_the_run_rebuilt_comes_back_too(workdir):
    """A failed run's `onerror`: an output a job that succeeded rebuilt (its record is not the
    snapshot's) comes back with its record, as a missing one does; an output no job touched,
    and a new one the snapshot never held, stay."""
    snap = snapshot(workdir)
    snap.take()
    table = workdir / RESULTS / "table.parquet"
    replace(table, "new table")
    record_path(workdir, RESULTS / "table.parquet").write_text("record of the new table")
    folder = workdir / RESULTS / "rollouts" / "fast"
    for p in folder.iterdir():
        p.unlink()
    write(folder / "ep-3.rrd", "new 3")
    record_path(workdir, RESULTS / "rollouts/fast").write_text("record of the new folder")
    write(workdir / RESULTS / "new.parquet", "a new output")

    assert snap.restore(replaced=True) == [RESULTS / "rollouts" / "fast", RESULTS / "table.parquet"]
    assert table.read_text() == "old table"
    assert {p.name: p.read_text() for p in folder.iterdir()} == {
        "ep-1.rrd": "old 1",
        "ep-2.rrd": "old 2",
    }
    for output in ("table.parquet", "rollouts/fast"):
        assert record_path(workdir, RESULTS / output).read_text() == f"record of old {output}"
    assert (workdir / RESULTS / "new.parquet").read_text() == "a new output"
    assert not [p for p in (workdir / RESULTS).rglob(".*.tmp-*")]


def _killed(snap: Snapshot, workdir: Path) -> None:
    """The snapshot now belongs to a run that is dead (no process has its start time)."""
    owner = snap.folder / "owner.json"
    owner.write_text(json.dumps(json.loads(owner.read_text()) | {"created": 0.0}))


def _killed_rebuilding_the_table(workdir: Path) -> tuple[Snapshot, Path]:
    """A run took its snapshot, started the table's job (marked incomplete, output removed)
    and was killed. Returns the snapshot and the table's path."""
    snap = snapshot(workdir)
    snap.take()
    table = RESULTS / "table.parquet"
    write(record_path(workdir, table, INCOMPLETE), "")
    (workdir / table).unlink()
    _killed(snap, workdir)
    return snap, table


def test_a_killed_run_gets_back_what_it_had_started_to_rebuild(workdir):
    snap, table = _killed_rebuilding_the_table(workdir)
    recovery = snapshot(workdir).recover()
    assert recovery.restored == (table,)
    assert (workdir / table).read_text() == "old table"
    assert not record_path(workdir, table, INCOMPLETE).exists()  # the mark is cleared
    assert not snap.folder.exists()


def test_a_killed_runs_temporaries_go_even_when_nothing_is_put_back(workdir):
    """Survey case 6 as CI met it: the kill came while a job filled its temporary folder, and
    every output came back from the snapshot, so the next run had nothing to do and no start
    to clear it at. The recovery itself removes it; a live run's temporaries stay."""
    from mjtrial.files.atomic import temp_path_for

    snap = snapshot(workdir)
    snap.take()
    left = temp_path_for(workdir / RESULTS / "rollouts" / "shard-00001")
    write(left / "episode.rrd", "half")
    live = snapshot(workdir).recover()  # this process owns the snapshot: alive
    assert live is None and left.exists()
    _killed(snap, workdir)
    recovery = snapshot(workdir).recover()
    assert recovery.removed == (left,) and recovery.restored == ()
    assert not left.exists()
    assert (workdir / RESULTS / "table.parquet").read_text() == "old table"


def test_what_the_user_deleted_after_a_kill_stays_deleted(workdir):
    """Survey case 7: only outputs the killed run marked incomplete come back."""
    snap = snapshot(workdir)
    snap.take()
    (workdir / RESULTS / "table.parquet").unlink()  # the user, not the run: no mark
    _killed(snap, workdir)
    assert snapshot(workdir).recover().restored == ()
    assert not (workdir / RESULTS / "table.parquet").exists()


def test_a_deleted_results_folder_takes_its_snapshot_with_it(workdir):
    """Survey case 7: the snapshot lives in the results folder, so deleting the folder deletes
    it and nothing can come back into it."""
    import shutil

    snap = snapshot(workdir)
    snap.take()
    write(record_path(workdir, RESULTS / "table.parquet", INCOMPLETE), "")
    shutil.rmtree(workdir / RESULTS)
    assert snapshot(workdir).recover() is None
    assert not (workdir / RESULTS).exists()


def test_a_live_runs_snapshot_is_left_alone(workdir):
    snap = snapshot(workdir)
    snap.take()  # owned by this very process, which is alive
    write(record_path(workdir, RESULTS / "table.parquet", INCOMPLETE), "")
    (workdir / RESULTS / "table.parquet").unlink()  # the live run is rebuilding it
    assert snapshot(workdir).recover() is None
    assert not (workdir / RESULTS / "table.parquet").exists() and snap.folder.exists()


def test_links_that_cannot_be_made_are_copies(workdir, monkeypatch):
    """Survey case 5: results on another filesystem than the snapshot (os.link: EXDEV)."""

    def cross_device(src, dst):
        raise OSError(errno.EXDEV, "Invalid cross-device link")

    monkeypatch.setattr(safekeeping.os, "link", cross_device)
    snap = snapshot(workdir)
    snap.take()
    folder = workdir / RESULTS / "rollouts" / "fast"
    for p in folder.iterdir():
        p.unlink()
    folder.rmdir()
    (workdir / RESULTS / "table.parquet").unlink()
    assert snap.restore() == [RESULTS / "rollouts" / "fast", RESULTS / "table.parquet"]
    assert (folder / "ep-2.rrd").read_text() == "old 2"


def test_a_snapshot_that_cannot_be_completed_stops_before_any_job(workdir, monkeypatch):
    """Survey case 5: a full disk while snapshotting raises, and leaves no partial snapshot."""

    def full(src, dst, **kwargs):
        raise OSError(errno.ENOSPC, "No space left on device")

    monkeypatch.setattr(safekeeping.os, "link", full)
    monkeypatch.setattr(safekeeping.shutil, "copy2", full)
    snap = snapshot(workdir)
    with pytest.raises(OSError, match="No space left"):
        snap.take()
    assert not snap.folder.exists()
    assert (workdir / RESULTS / "table.parquet").read_text() == "old table"


def test_a_snapshot_that_cannot_be_used_is_set_aside(workdir, monkeypatch):
    """Survey case 5: a killed run's snapshot that fails to restore never wedges later runs."""
    snap = snapshot(workdir)
    snap.take()
    write(record_path(workdir, RESULTS / "table.parquet", INCOMPLETE), "")
    (workdir / RESULTS / "table.parquet").unlink()
    _killed(snap, workdir)

    def broken(src, dst, **kwargs):
        raise OSError(errno.EIO, "Input/output error")

    monkeypatch.setattr(safekeeping.os, "link", broken)
    monkeypatch.setattr(safekeeping.shutil, "copy2", broken)
    recovery = snapshot(workdir).recover()
    assert "Input/output error" in recovery.error
    assert recovery.set_aside.name.startswith(".snapshot-broken-")
    assert recovery.set_aside.is_dir() and not snap.folder.exists()
    monkeypatch.undo()
    assert snapshot(workdir).recover() is None  # the next run is not in its way
    snapshot(workdir).take()


def test_hidden_temporaries_are_not_kept_and_stale_ones_are_removed(workdir):
    temp_file = workdir / RESULTS / ".table.parquet.tmp-123-ab.parquet"
    temp_dir = workdir / RESULTS / "rollouts" / ".slow.tmp-9-cd"
    write(temp_file, "half")
    write(temp_dir / "ep.rrd", "half")
    snap = snapshot(workdir)
    snap.take()
    assert not any(".tmp-" in str(p) for p in snap.folder.rglob("*"))
    assert remove_stale_temporaries(workdir / RESULTS) == sorted([temp_dir, temp_file])
    assert not temp_file.exists() and not temp_dir.exists()
    assert (workdir / RESULTS / "table.parquet").exists()


def test_a_temporary_that_cannot_be_removed_stays_unreported_and_the_recovery_goes_on(
    workdir, monkeypatch
):
    """Removing temporaries is best effort: one the filesystem refuses (a read-only folder
    for another user) stays for the next try and is not said to be removed, and the killed
    run's outputs still come back."""
    stuck = workdir / RESULTS / ".manifest.json.tmp-7-ef.json"
    gone = workdir / RESULTS / ".summary.json.tmp-7-01.json"
    write(stuck, "half")
    write(gone, "half")
    _, table = _killed_rebuilding_the_table(workdir)
    unlink = Path.unlink

    def refuse(self, *args, **kwargs):
        if self == stuck:
            raise PermissionError(errno.EACCES, "Permission denied", str(self))
        return unlink(self, *args, **kwargs)

    monkeypatch.setattr(Path, "unlink", refuse)
    recovery = snapshot(workdir).recover()
    assert recovery.removed == (gone,) and recovery.error == ""
    assert recovery.restored == (table,) and (workdir / table).read_text() == "old table"
    assert stuck.exists() and not gone.exists()
