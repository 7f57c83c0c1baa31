"""The snapshot that puts back what a failed run removed, on a hand-made results folder.

The end-to-end cases (a real failing job under Snakemake) are in test_trust.py.
"""

from __future__ import annotations

import base64
import os
from pathlib import Path

import pytest

from mjtrial.safekeeping import METADATA, Snapshot, remove_stale_temporaries

RESULTS = Path("results/x")


def record_path(workdir: Path, output: Path) -> Path:
    """Where Snakemake keeps an output's metadata record: its path in urlsafe base64."""
    return workdir / METADATA / base64.urlsafe_b64encode(str(output).encode()).decode()


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
    assert snap.take() == []
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


def test_a_killed_run_is_repaired_by_the_next_start(workdir):
    snapshot(workdir).take()
    (workdir / RESULTS / "table.parquet").unlink()  # then the run was killed: no handler ran
    snap = snapshot(workdir)
    assert snap.take() == [RESULTS / "table.parquet"]
    assert (workdir / RESULTS / "table.parquet").read_text() == "old table"
    snap.drop()
    assert not snap.folder.exists()


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
