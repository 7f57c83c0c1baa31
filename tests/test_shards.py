"""Shards: results never depend on the shard size or the thread count, an interrupted run
resumes by shard, recordings can be limited to failures or left out, failures.rrd is bounded."""

from __future__ import annotations

import os
import re
import shutil
import signal
import subprocess
import time
from pathlib import Path

import pyarrow.parquet as pq
import pytest
from conftest import SNAKEMAKE, edit_config, run_snakemake

from mjtrial.files.layout import Layout
from mjtrial.recording import list_recordings
from mjtrial.replay import read_episode
from mjtrial.stages.failures import choose_failures
from mjtrial.verify import verify_results

pytestmark = pytest.mark.end_to_end

LAYOUT = Layout.of("research_mode")
CONDITIONS = ("fast", "slow")


def tables(workdir: Path) -> dict[str, object]:
    return {
        c: pq.read_table(workdir / LAYOUT.rollout_table(c)).replace_schema_metadata(None)
        for c in CONDITIONS
    }


# What the shard tests compare: the gathered tables (and their shards' recordings), built
# without what reads them (analysis, figures, report, seal, crate).
TABLES = [LAYOUT.rollout_table(c).as_posix() for c in CONDITIONS]


def copy_of(built: Path, tmp_path: Path, edit=None) -> Path:
    workdir = tmp_path / "copy"
    shutil.copytree(built, workdir, symlinks=True)
    shutil.rmtree(workdir / "results")
    shutil.rmtree(workdir / ".snakemake", ignore_errors=True)
    if edit:
        edit_config(workdir, edit)
    return workdir


def test_results_do_not_depend_on_shard_size_or_threads(built, tmp_path):
    """The small experiment runs 12 states in shards of 5 (5, 5, 2) on 2 threads; here in one
    shard of 12 on 1 thread (its tables and recordings only)."""
    assert len(list((built / LAYOUT.recordings("fast")).glob("*.parquet"))) == 3
    workdir = copy_of(built, tmp_path, lambda c: c["rollout"].update(shard_size=1000))
    run_snakemake(workdir, *TABLES, "--set-threads", "rollout=1")  # it takes every word after
    assert [p.name for p in (workdir / LAYOUT.recordings("fast")).glob("*.parquet")] == [
        "shard-00000.parquet"
    ]
    ours, theirs = tables(workdir), tables(built)
    for c in CONDITIONS:
        assert ours[c].equals(theirs[c]), c
        for state_id in (0, 7, 11):  # one episode in each shard
            a = read_episode(workdir / LAYOUT.root, condition=c, state_id=state_id)
            b = read_episode(built / LAYOUT.root, condition=c, state_id=state_id)
            assert a.keys() == b.keys()
            for key in a:
                assert (a[key] == b[key]).all(), (c, state_id, key)


def test_an_interrupted_run_resumes_by_shard(built, tmp_path):
    """The rollouts and their gathers only (`TABLES`), killed then resumed."""
    workdir = copy_of(built, tmp_path, lambda c: c["rollout"].update(shard_size=4))
    proc = subprocess.Popen(
        [SNAKEMAKE, "-c2", *TABLES],
        cwd=workdir,
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
        start_new_session=True,
    )
    # Two rollout jobs run side by side (one core each). A job that began after another had
    # finished was started by Snakemake once it had recorded the finished one as complete: so
    # once a third shard's table is there, at least one shard is finished and recorded, and
    # at most the two jobs running at the kill are unfinished or unrecorded.
    shards = [
        workdir / LAYOUT.shard_table(c, s) for c in CONDITIONS for s in ("00000", "00001", "00002")
    ]
    deadline = time.monotonic() + 180
    while sum(p.exists() for p in shards) < 3 and time.monotonic() < deadline:
        time.sleep(0.02)
    os.killpg(proc.pid, signal.SIGKILL)
    proc.wait()
    done = [p for p in shards if p.exists()]
    assert len(done) >= 3, "fewer than three shards finished before the kill"
    finished = {p: p.read_bytes() for p in done}
    run_snakemake(workdir, "--unlock")
    out = run_snakemake(workdir, "-n", "--rerun-incomplete", *TABLES).stdout
    planned = int(out.split("Job stats:")[1].split("rollout")[1].split()[0])
    assert planned <= 6 - (len(done) - 2)  # at most the two running at the kill run again
    run_snakemake(workdir, "--rerun-incomplete", *TABLES)
    kept = [p for p in done if p.read_bytes() == finished[p]]
    assert len(kept) >= len(done) - 2  # finished shards are not run again
    ours, theirs = tables(workdir), tables(built)
    assert all(ours[c].equals(theirs[c]) for c in CONDITIONS)


def test_only_failures_recorded_and_failures_rrd_bounded(built, tmp_path):
    workdir = copy_of(
        built,
        tmp_path,
        lambda c: c["recording"].update(episodes="failed", failures_max=3),
    )
    run_snakemake(workdir)
    failures = pq.read_table(workdir / LAYOUT.failures_table).to_pylist()
    for c in CONDITIONS:
        table = pq.read_table(workdir / LAYOUT.rollout_table(c)).to_pylist()
        failed = {r["state_id"] for r in table if not r["success"]}
        recorded = {
            r["state_id"]
            for shard in (workdir / LAYOUT.recordings(c)).glob("shard-*/")
            for r in list_recordings(shard)
            if "state_id" in r
        }
        assert recorded == failed, c
        assert {r["state_id"] for r in failures if r["condition"] == c} == failed
        succeeded = sorted({r["state_id"] for r in table} - failed)
        if succeeded:
            with pytest.raises(KeyError, match="only failures are recorded"):
                read_episode(workdir / LAYOUT.root, condition=c, state_id=succeeded[0])
    in_rrd = [r for r in failures if r["in_failures_rrd"]]
    assert len(in_rrd) == min(3, len(failures))
    copied = [r for r in list_recordings(workdir / LAYOUT.failures) if "state_id" in r]
    assert {(r["condition"], r["state_id"]) for r in copied} == {
        (r["condition"], r["state_id"]) for r in in_rrd
    }
    report = verify_results(
        workdir / LAYOUT.root, config_path=workdir / "config" / "config.yaml", repo_root=workdir
    )
    assert report.ok, report.format()


def test_no_recordings(built, tmp_path):
    workdir = copy_of(built, tmp_path, lambda c: c["recording"].update(episodes="none"))
    run_snakemake(workdir)
    assert not (workdir / LAYOUT.shard_recordings("fast", "00000")).exists()
    assert not (workdir / LAYOUT.failures).exists()
    ours, theirs = tables(workdir), tables(built)
    assert all(ours[c].equals(theirs[c]) for c in CONDITIONS)
    report = verify_results(
        workdir / LAYOUT.root, config_path=workdir / "config" / "config.yaml", repo_root=workdir
    )
    assert report.ok, report.format()


def test_failures_are_chosen_round_robin_over_conditions_and_categories():
    failures = [
        ("fast", 9, "slipped during the lift"),
        ("fast", 2, "slipped during the lift"),
        ("fast", 5, "never grasped"),
        ("slow", 4, "dropped during the hold"),
        ("fast", 1, "slipped during the lift"),
    ]
    # Groups in name order: (fast, never grasped), (fast, slipped), (slow, dropped).
    assert choose_failures(failures, at_most=3) == {("fast", 5), ("fast", 1), ("slow", 4)}
    assert choose_failures(failures, at_most=4) == {
        ("fast", 5),
        ("fast", 1),
        ("slow", 4),
        ("fast", 2),
    }
    assert len(choose_failures(failures, at_most=100)) == 5
    assert choose_failures(failures, at_most=0) == set()


def test_a_rollout_log_tells_its_progress(built):
    log = (built / LAYOUT.log("rollout_fast_00000")).read_text()
    assert re.search(r"rollout:fast#00000: 5/5 episodes, [\d.]+ episodes/s, 0 s left", log)
