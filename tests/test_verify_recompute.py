"""`mjtrial verify` recomputes, it does not trust the seal (survey case 2): forged links that
every stamp and seal agree with are named, by recomputing the light stages from their inputs
and re-simulating episodes. Each end-to-end test failed before the recomputation existed."""

from __future__ import annotations

import dataclasses
import json
import shutil
import time
import zlib
from datetime import datetime, timezone
from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
import pytest
from conftest import edit_config, run_snakemake

from mjtrial import provenance
from mjtrial.sim import resimulation
from mjtrial.verify import Status, verify_results
from mjtrial.verify.recompute import (
    json_difference,
    markdown_difference,
    sample_ids,
    table_difference,
)

pytestmark = pytest.mark.end_to_end

RESULTS = Path("results") / "research_mode"
REPORT = (RESULTS / "report.md").as_posix()
SUMMARY = (RESULTS / "analysis" / "summary.json").as_posix()
MANIFEST = (RESULTS / "manifest.json").as_posix()


def copy_of(built: Path, tmp_path: Path) -> Path:
    workdir = tmp_path / "copy"
    shutil.copytree(built, workdir, symlinks=True)
    return workdir


def verified(workdir: Path, **kwargs):
    return verify_results(
        workdir / RESULTS,
        config_path=workdir / "config" / "config.yaml",
        repo_root=workdir,
        **kwargs,
    )


def now_utc() -> str:
    time.sleep(1.1)  # stamps have a resolution of one second
    return datetime.now(timezone.utc).strftime("%Y-%m-%dT%H:%M:%SZ")


def test_a_fresh_build_recomputes_equal(built):
    report = verified(built, resimulate=5, seed=7)
    assert report.ok, report.format()
    [line] = report.checks
    # states, 2 gathered tables, 2 nominal episodes, 6 shard tables, summary, manifest, report,
    # the crate and its copy of the sources; 12 states' episodes under 2 conditions recorded
    assert line == (
        "recomputed 16 outputs from their inputs, compared 24 recorded episodes with their rows "
        "and re-simulated 24 of 24 episodes (sample seed 7: --seed 7 draws it again): 0 differ"
    )


def test_the_command_prints_its_sample_seed_and_seed_draws_that_sample(built, monkeypatch, capsys):
    from mjtrial import cli

    monkeypatch.chdir(built)
    assert cli.main(["verify", "--resimulate", "1"]) == 0
    line = capsys.readouterr().out.splitlines()[-2]
    seed = line.split("(sample seed ")[1].split(":")[0]
    assert f"--seed {seed} draws it again" in line
    assert cli.main(["verify", "--resimulate", "1", "--seed", "12"]) == 0
    assert "re-simulated 6 of 24 episodes (sample seed 12: --seed 12 draws it again)" in (
        capsys.readouterr().out
    )


def test_an_edited_report_with_its_seal_deleted_is_named(built, tmp_path):
    """Edit report.md, delete seal.json, rebuild: only the seal reran and sealed the edit."""
    workdir = copy_of(built, tmp_path)
    report_md = workdir / REPORT
    text = report_md.read_text()
    assert "Verdict: **REFUTED**" in text  # 12 states are too few to support the hypothesis
    report_md.write_text(text.replace("Verdict: **REFUTED**", "Verdict: **SUPPORTED**"))
    (workdir / RESULTS / "seal.json").unlink()
    run_snakemake(workdir)
    report = verified(workdir)
    assert report[REPORT].status is Status.TAMPERED, report.format()
    why = " ".join(report[REPORT].reasons)
    assert "differs from its recomputation" in why and "REFUTED" in why and "SUPPORTED" in why
    assert report.with_status(Status.TAMPERED) == [REPORT]


def test_a_forged_summary_restamped_with_the_manifest_forced_is_named(built, tmp_path):
    """Rewrite summary.json with another verdict, refresh its stamp's time, rebuild the
    manifest (and so the report): every stamp agrees, and the report says SUPPORTED."""
    workdir = copy_of(built, tmp_path)
    path = workdir / SUMMARY
    summary = json.loads(path.read_text())
    stamp = dict(summary.pop("provenance"), created_utc=now_utc())
    assert summary["falsifier"]["verdict"] == "refuted"
    summary["falsifier"]["verdict"] = "supported"
    provenance.write_json(summary, path, stamp)
    run_snakemake(workdir, "--forcerun", "manifest")
    assert "**SUPPORTED**" in (workdir / REPORT).read_text()

    report = verified(workdir)
    assert report[SUMMARY].status is Status.TAMPERED, report.format()
    assert 'falsifier.verdict: "supported" -> "refuted"' in " ".join(report[SUMMARY].reasons)
    # Built from the forgery: stale, a rebuild fixes them.
    for downstream in (MANIFEST, REPORT):
        assert report[downstream].status is Status.STALE
        assert "input tampered" in " ".join(report[downstream].reasons)


def _yesterdays_sample(first: int, stop: int, k: int, key: str) -> list[int]:
    """The sample verify re-simulated before issue 26: a function of the shard's path alone,
    which a forger can compute (written out here, as a forger would)."""
    rng = np.random.default_rng(zlib.crc32(key.encode()))
    return sorted(rng.choice(np.arange(first, stop), size=k, replace=False).tolist())


def _flip_to_success(path: Path, state_id: int) -> None:
    """A forger's edit: the state's row a success without a category, under a fresh stamp."""
    stamp = dict(provenance.read_stamp(path), created_utc=now_utc())
    table = pq.read_table(path).replace_schema_metadata(None)
    row = table.column("state_id").to_pylist().index(state_id)
    for name, value in (("success", True), ("failure_category", None)):
        values = table.column(name).to_pylist()
        values[row] = value
        i = table.column_names.index(name)
        table = table.set_column(i, name, pa.array(values, type=table.schema.field(i).type))
    if provenance.ROWS_KEY in stamp["extra"]:  # a shard: its stamp records its rows too
        stamp["extra"] = {**stamp["extra"], provenance.ROWS_KEY: provenance.rows_sha256(table)}
    provenance.write_parquet(table, path, stamp)


def test_a_flipped_failure_outside_the_resimulated_sample_is_named_by_its_recording(
    built, tmp_path
):
    """Issue 26 case 5: flip a failed episode that the deterministic sample of 2 per shard
    leaves out, in its shard's table and the gathered one, rebuild what follows: its recording
    still says it failed, and verify names it (before, "0 differ" and one success more)."""
    workdir = copy_of(built, tmp_path)
    rollouts = workdir / RESULTS / "rollouts"
    forged = None
    for condition in ("fast", "slow"):
        gathered = pq.read_table(rollouts / f"{condition}.parquet")
        ids = np.array(gathered.column("state_id").to_pylist())
        success = np.array(gathered.column("success").to_pylist())
        # The report draws the three lowest-id successes from their recordings
        # (mjtrial.report.traces): the forger flips a failure it will not draw as one.
        for state_id in ids[~success]:
            first = int(state_id) // 5 * 5
            shard = rollouts / condition / f"shard-{first // 5:05d}.parquet"
            key = shard.relative_to(workdir).as_posix()
            sampled = _yesterdays_sample(first, min(first + 5, 12), 2, key)
            if state_id not in sampled and state_id > max(ids[success][:3]):
                forged = (condition, int(state_id), shard)
                break
        if forged:
            break
    assert forged, "expected a failed episode outside the sample in the built run"
    condition, state_id, shard = forged
    _flip_to_success(shard, state_id)
    _flip_to_success(rollouts / f"{condition}.parquet", state_id)
    run_snakemake(workdir)

    report = verified(workdir, resimulate=2)
    rel = shard.relative_to(workdir).as_posix()
    assert report[rel].status is Status.TAMPERED, report.format()
    reasons = " ".join(report[rel].reasons)
    assert f"state {state_id}: recorded success False differs from True" in reasons, reasons


def test_an_outcome_that_depends_on_its_batch_is_not_reconfirmed_in_its_batch(built, monkeypatch):
    """Issue 26 case 1: a task whose final height is another alone than beside other episodes
    (as the run's batches of 5 and 2 had them). Re-simulated in the run's batches, the sample
    agreed with the tables; re-simulated in another composition, it does not."""
    real = resimulation.condition_task

    def batch_dependent(*args, **kwargs):
        bound = real(*args, **kwargs)
        task = bound.task

        def measure(episodes, own=task.measure):
            measures = dict(own(episodes))
            if len(episodes.physics) == 1:
                measures["final_height"] = measures["final_height"] + 1e-3
            return measures

        return dataclasses.replace(bound, task=dataclasses.replace(task, measure=measure))

    monkeypatch.setattr(resimulation, "condition_task", batch_dependent)
    report = verified(built, resimulate=5)
    shard = (RESULTS / "rollouts" / "fast" / "shard-00000.parquet").as_posix()
    assert report[shard].status is Status.TAMPERED, report.format()
    assert "differ in final_height" in " ".join(report[shard].reasons)


def test_an_outcome_that_is_not_reproducible_is_named_as_such_never_as_tampering(
    built, monkeypatch
):
    """Issue 42 item 11: a task whose code draws unseeded randomness (here its measure: each
    re-simulation's final height its own) makes honest files differ from their re-simulation.
    Verify re-simulates once more, finds the two disagree, and says the run cannot be
    reproduced: not tampered, and not verified."""
    real = resimulation.condition_task

    def unseeded(*args, **kwargs):
        bound = real(*args, **kwargs)
        task = bound.task

        def measure(episodes, own=task.measure):
            measures = dict(own(episodes))
            noise = np.random.default_rng().normal(0.0, 1e-3, len(episodes.physics))
            measures["final_height"] = measures["final_height"] + noise
            return measures

        return dataclasses.replace(bound, task=dataclasses.replace(task, measure=measure))

    monkeypatch.setattr(resimulation, "condition_task", unseeded)
    report = verified(built, resimulate=2, seed=3)
    shard = (RESULTS / "rollouts" / "fast" / "shard-00000.parquet").as_posix()
    assert report[shard].status is Status.IRREPRODUCIBLE, report.format()
    [reason] = report[shard].reasons
    assert reason.startswith("differs from its re-simulation (re-simulated episodes for states ")
    assert "re-simulated twice here the two disagree (two re-simulations for states " in reason
    assert "the task's code is not a function of its arguments" in reason
    assert Status.TAMPERED not in {o.status for o in report.outputs}, report.format()
    assert not report.ok and report.exit_code == 1
    assert " irreproducible (" in report.summary() and report.summary().startswith("NOT verified")


def test_a_file_deleted_from_a_folder_of_recordings_is_named_with_its_rebuild(built, tmp_path):
    """Issue 42 item 14: a folder of recordings is one output, so Snakemake saw a deleted file
    in it (a mesh store, an episode's recording) as "Nothing to be done", and verify named the
    whole folder. Now the workflow's load and verify name what is missing and the command that
    rebuilds it, and that command does."""
    workdir = copy_of(built, tmp_path)
    folder = RESULTS / "rollouts" / "fast" / "shard-00000"
    episodes = sorted((workdir / folder).glob("*.rrd"))
    episodes[0].unlink()
    problem = (
        f"{folder.as_posix()}: 1 of its {len(episodes)} episodes' recordings missing "
        f"(recordings.json records it); `snakemake -c2 -R {folder.as_posix()}` rebuilds its "
        "folder and what was made from it"
    )
    report = verified(workdir, resimulate=0)
    assert report[folder.as_posix()].reasons[0] == problem, report.format()
    assert not report.ok
    # the workflow's load names it (on any start: here the one that rebuilds it) ...
    rebuilt = run_snakemake(workdir, "-R", folder.as_posix())
    assert f"mjtrial: {problem}" in rebuilt.stderr.splitlines(), rebuilt.stderr
    assert episodes[0].is_file()  # ... and the command it gives rebuilds it
    report = verified(workdir, resimulate=0)
    assert report.ok, report.format()


def nudge_final_x(shard: Path, *, row: int) -> None:
    """Add 1e-6 to one episode's final x in a shard table, under the table's own stamp: a
    forgery that no stamp, seal or recording shows (the recordings do not carry final x)."""
    stamp = provenance.read_stamp(shard)
    table = pq.read_table(shard).replace_schema_metadata(None)
    final_x = table.column("final_x").to_numpy().copy()
    final_x[row] += 1e-6
    table = table.set_column(table.column_names.index("final_x"), "final_x", pa.array(final_x))
    stamp["extra"][provenance.ROWS_KEY] = provenance.rows_sha256(table)  # the forger restamps
    provenance.write_parquet(table, shard, stamp)


def test_a_forged_episode_rebuilt_downstream_is_found_by_resimulation(built, tmp_path):
    """Nudge an episode's final x (a measure its recording does not carry: a recorded one,
    its recording names) in a shard table under its own stamp and let Snakemake rebuild
    everything after it: only re-simulating the episode can tell. (Flipping its success is
    caught by its recording, which says otherwise: the test above; a stamp made after the job
    ended, by the crate's record of the job's times: test_crate.)"""
    workdir = copy_of(built, tmp_path)
    shard = workdir / RESULTS / "rollouts" / "slow" / "shard-00001.parquet"
    nudge_final_x(shard, row=2)  # state 7
    run_snakemake(workdir)

    assert verified(workdir, resimulate=0).ok  # every stamp, seal and recording agrees
    report = verified(workdir, resimulate=5)  # shards hold 5 states: all re-simulated
    rel = shard.relative_to(workdir).as_posix()
    assert report[rel].status is Status.TAMPERED, report.format()
    reasons = " ".join(report[rel].reasons)
    assert "re-simulated episodes for states 7 differ in final_x" in reasons
    assert report[SUMMARY].status is Status.STALE


@pytest.fixture(scope="module")
def studied(built, tmp_path_factory) -> Path:
    workdir = tmp_path_factory.mktemp("recompute-studies") / "copy"
    shutil.copytree(built, workdir, symlinks=True)

    def one_variant(config):
        config["variants"] = {"small_step": {"option": {"timestep": 0.001}}}

    edit_config(workdir, one_variant)
    run_snakemake(workdir, "sensitivity")
    return workdir


def test_an_edited_study_report_beside_a_deleted_summary_is_named(studied, tmp_path):
    """Change "survives 0 of 1" in the sensitivity report, delete its summary and its seal:
    the summary is missing and the report differs from what the tables give."""
    workdir = copy_of(studied, tmp_path)
    assert verified(workdir, resimulate=1).ok
    report_md = workdir / RESULTS / "report_sensitivity.md"
    text = report_md.read_text()
    assert "survives 0 of 1" in text, text
    report_md.write_text(text.replace("survives 0 of 1", "survives 1 of 1"))
    (workdir / RESULTS / "analysis" / "sensitivity.json").unlink()
    (workdir / RESULTS / "seal_sensitivity.json").unlink()

    report = verified(workdir, resimulate=1)
    rel = (RESULTS / "report_sensitivity.md").as_posix()
    assert report[rel].status is Status.TAMPERED, report.format()
    assert "survives 1 of 1" in " ".join(report[rel].reasons)
    assert report[(RESULTS / "analysis" / "sensitivity.json").as_posix()].status is Status.MISSING
    assert report[(RESULTS / "seal_sensitivity.json").as_posix()].status is Status.MISSING


# --------------------------------------------------------------------------------------------
# The comparisons, against hand-made references
# --------------------------------------------------------------------------------------------


def test_json_difference_ignores_the_stamp_and_names_the_keys(tmp_path):
    path = tmp_path / "a.json"
    path.write_text(json.dumps({"a": {"b": 1, "c": [1, 2]}, "nan": float("nan"), "provenance": 1}))
    assert json_difference(path, {"a": {"b": 1, "c": (1, 2)}, "nan": float("nan")}) is None
    assert json_difference(path, {"a": {"b": 2, "c": [1, 2]}, "nan": float("nan")}) == (
        "a.b: 1 -> 2 (file -> recomputed)"
    )


def test_markdown_difference_names_the_first_differing_line(tmp_path):
    path = tmp_path / "r.md"
    path.write_text("---\nprovenance: {}\n---\n# Title\nsame\nold line\n")
    assert markdown_difference(path, "# Title\nsame\nold line\n") is None
    assert markdown_difference(path, "# Title\nsame\nnew line\n") == (
        "line 3: 'old line' in the file, 'new line' recomputed"
    )


def test_table_difference_names_states_and_columns():
    table = pa.table({"state_id": [0, 1, 2], "x": [0.5, np.nan, 2.0], "c": ["a", None, "b"]})
    assert table_difference(table, {"x": np.array([0.5, np.nan, 2.0])}) is None
    assert table_difference(table, {"c": np.array(["a", None, "b"], dtype=object)}) is None
    assert table_difference(table, {"x": np.array([0.5, np.nan, 3.0])}) == (
        "rows for states 2 differ in x"
    )
    assert table_difference(table, {"x": np.array([0.5])}) == "3 rows, 1 recomputed"


def test_the_resimulated_sample_is_fixed_by_the_seed_and_shard_and_covers_small_shards():
    fast = "results/x/rollouts/fast/shard-00001.parquet"
    a = sample_ids(1000, 2000, 20, seed=1, key=fast)
    assert a == sample_ids(1000, 2000, 20, seed=1, key=fast)  # --seed repeats a check
    assert a != sample_ids(1000, 2000, 20, seed=2, key=fast)
    assert a != sample_ids(1000, 2000, 20, seed=1, key=fast.replace("fast", "slow"))
    assert len(set(a)) == 20 and all(1000 <= i < 2000 for i in a) and a == sorted(a)
    assert sample_ids(10, 12, 20, seed=1, key="k") == [10, 11]


def test_a_record_s_difference_from_its_row_names_plain_values():
    """The table's columns are numpy arrays: their values are said as Python's (`np.True_`,
    `np.float64(2.5)` before)."""
    from mjtrial.report.traces import record_difference

    row = {"success": np.True_, "lift": np.float64(2.5)}
    assert record_difference({"success": False}, row) == "recorded success False differs from True"
    assert record_difference({"success": True, "lift": 1.0}, row) == (
        "recorded lift 1.0 differs from 2.5"
    )
