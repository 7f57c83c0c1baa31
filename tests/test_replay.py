"""Replays reproduce what the pipeline recorded; the logged trajectories agree with the tables."""

from __future__ import annotations

import shutil

import pyarrow as pa
import pyarrow.parquet as pq
import pytest

from mjtrial import provenance
from mjtrial.recording import list_recordings
from mjtrial.replay import ReplayMismatch, read_episode, replay_episode

pytestmark = pytest.mark.end_to_end


def _rollouts(built, condition):
    return pq.read_table(built / "results" / "research_mode" / "rollouts" / f"{condition}.parquet")


SHARD_SIZE = 5  # the built experiment's rollout.shard_size (conftest)


@pytest.mark.parametrize("condition", ["fast", "slow"])
def test_logged_trajectories_match_the_tables(built, condition):
    results = built / "results" / "research_mode"
    table = _rollouts(built, condition)
    shards = sorted(p for p in (results / "rollouts" / condition).iterdir() if p.is_dir())
    assert len(shards) == 3  # 12 states in shards of 5
    for shard in shards:  # a folder: one .rrd per episode of the shard's states
        first = int(shard.name.removeprefix("shard-")) * SHARD_SIZE
        assert [r["state_id"] for r in list_recordings(shard)] == list(
            range(first, min(first + SHARD_SIZE, table.num_rows))
        )
    for row in table.to_pylist():
        # Found by the results folder (in whichever shard), the shard's folder and the file.
        shard = shards[row["state_id"] // SHARD_SIZE]
        file = shard / f"{condition}-state-{row['state_id']:06d}.rrd"
        for where in (results, shard, file):
            episode = read_episode(where, condition=condition, state_id=row["state_id"])
            assert episode["cube_height"][-1] == row["final_height"]
            assert bool(episode["cube_height"][-1] > 0.2) == row["success"]
    with pytest.raises(KeyError, match="no recording"):
        read_episode(results, condition=condition, state_id=table.num_rows)


def test_failures_file_holds_every_failed_episode(built):
    results = built / "results" / "research_mode"
    failed = {
        (c, r["state_id"])
        for c in ("fast", "slow")
        for r in _rollouts(built, c).to_pylist()
        if not r["success"]
    }
    assert failed, "the small experiment should have failures to gather"
    listed = {
        (r["condition"], r["state_id"])
        for r in list_recordings(results / "replay" / "failures.rrd")
        if "state_id" in r
    }
    assert listed == failed
    # failures.parquet lists every failure with its category, each also in failures.rrd here
    # (fewer than recording.failures_max).
    rows = pq.read_table(results / "replay" / "failures.parquet").to_pylist()
    categories = {
        (c, r["state_id"]): r["failure_category"]
        for c in ("fast", "slow")
        for r in _rollouts(built, c).to_pylist()
        if not r["success"]
    }
    assert {(r["condition"], r["state_id"]): r["failure_category"] for r in rows} == categories
    assert len(rows) == len(failed) and all(r["in_failures_rrd"] for r in rows)


def test_replay_reproduces_recorded_failures(built, tmp_path):
    failed = [
        (c, r)
        for c in ("fast", "slow")
        for r in _rollouts(built, c).to_pylist()
        if not r["success"]
    ]
    for condition, row in failed[:3]:
        out = tmp_path / f"{condition}_{row['state_id']}.rrd"
        replay = replay_episode(
            condition=condition, state_id=row["state_id"], output=out, repo_root=built
        )
        assert replay.outcome["final_height"] == row["final_height"]
        assert replay.outcome["failure_category"] == row["failure_category"]
        episode = read_episode(out, condition=condition, state_id=row["state_id"])
        # Full simulation rate: one logged row per physics step.
        assert len(episode["cube_height"]) in (1425, 2100)
        assert episode["cube_height"][-1] == row["final_height"]
        assert provenance.read_stamp(out)["rule"] == "replay"


def test_a_replay_is_written_outside_the_sealed_results_folder_by_default(built, tmp_path):
    """Issue 42 item 15: `mjtrial replay` wrote `results/<exp>/replay/...` by default, a file
    in the sealed folder that no rule makes; now `replays/<exp>/` beside the results."""
    workdir = tmp_path / "copy"
    shutil.copytree(built, workdir)
    results = workdir / "results" / "research_mode"
    before = sorted(p.relative_to(results) for p in results.rglob("*"))
    state_id = _rollouts(built, "slow").column("state_id")[2].as_py()
    replay = replay_episode(condition="slow", state_id=state_id, repo_root=workdir)
    expected = workdir / "replays" / "research_mode" / f"slow_state{state_id}.rrd"
    assert replay.recording == expected and expected.is_file()
    assert sorted(p.relative_to(results) for p in results.rglob("*")) == before


def test_replay_reports_what_differs(built, tmp_path):
    workdir = tmp_path / "copy"
    shutil.copytree(built, workdir)
    path = workdir / "results" / "research_mode" / "rollouts" / "fast.parquet"
    table = pq.read_table(path)
    heights = table.column("final_height").to_numpy().copy()
    heights[0] += 1e-9  # a result that no longer matches what the engine produces
    stamp = provenance.read_stamp(path)
    tampered = table.set_column(
        table.column_names.index("final_height"), "final_height", pa.array(heights)
    )
    provenance.write_parquet(tampered, path, stamp)
    state_id = table.column("state_id")[0].as_py()
    with pytest.raises(ReplayMismatch, match=r"fast state \d+ does not reproduce: final_height"):
        replay_episode(
            condition="fast", state_id=state_id, output=tmp_path / "x.rrd", repo_root=workdir
        )
    with pytest.raises(KeyError, match="no episode for state 999"):
        replay_episode(condition="fast", state_id=999, output=tmp_path / "y.rrd", repo_root=workdir)


def test_every_rrd_passes_rerun_verify(built):
    import os
    import subprocess
    import sys
    from pathlib import Path

    rerun = Path(sys.executable).parent / "rerun"
    results = built / "results" / "research_mode"
    files = sorted(results.rglob("*.rrd"))
    assert len(files) == 2 * 12 + 1  # every episode of both conditions, and failures.rrd
    env = {**os.environ, "CI": "1"}  # rerun's CLI writes no analytics files when CI is set
    for path in [*files, *results.rglob("*.rbl")]:
        proc = subprocess.run(
            [str(rerun), "rrd", "verify", str(path)], capture_output=True, text=True, env=env
        )
        assert proc.returncode == 0, f"{path}: {proc.stderr[-500:]}"


def test_failures_come_from_the_tables_and_must_agree_with_the_recordings(built, tmp_path):
    from mjtrial.stages.failures import gather_failures

    rollouts = built / "results" / "research_mode" / "rollouts"
    folders = {c: rollouts / c for c in ("fast", "slow")}
    shards = {c: sorted(p for p in folders[c].glob("shard-*") if p.is_dir()) for c in folders}
    tables = {c: rollouts / f"{c}.parquet" for c in ("fast", "slow")}
    out = tmp_path / "failures.rrd"
    failed = sum(not r["success"] for t in tables.values() for r in pq.read_table(t).to_pylist())
    assert failed > 1
    assert (
        gather_failures(
            tables=tables,
            failures_max=200,
            shard_folders=shards,
            output=out,
            output_table=tmp_path / "failures.parquet",
        )
        == failed
    )
    # At most failures_max in the .rrd; the table still lists every failure.
    assert (
        gather_failures(
            tables=tables,
            failures_max=1,
            shard_folders=shards,
            output=tmp_path / "one.rrd",
            output_table=tmp_path / "one.parquet",
        )
        == 1
    )
    assert len([r for r in list_recordings(tmp_path / "one.rrd") if "state_id" in r]) == 1
    listed = pq.read_table(tmp_path / "one.parquet").to_pylist()
    assert len(listed) == failed and sum(r["in_failures_rrd"] for r in listed) == 1

    # A table that calls a successful episode failed: the recordings disagree, nothing written.
    table = pq.read_table(tables["slow"])
    success = table.column("success").to_pylist()
    first_success = success.index(True)
    success[first_success] = False
    edited = tmp_path / "slow.parquet"
    table = table.set_column(table.schema.get_field_index("success"), "success", pa.array(success))
    provenance.write_parquet(
        table.replace_schema_metadata(None), edited, provenance.read_stamp(tables["slow"])
    )
    with pytest.raises(ValueError, match=f"slow-state-{first_success:06d}.*not a failed episode"):
        gather_failures(
            tables={"fast": tables["fast"], "slow": edited},
            failures_max=200,
            shard_folders=shards,
            output=tmp_path / "bad.rrd",
            output_table=tmp_path / "bad.parquet",
        )
    assert not (tmp_path / "bad.rrd").exists()
    assert not (tmp_path / "bad.parquet").exists()
