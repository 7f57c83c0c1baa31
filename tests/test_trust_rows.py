"""The fourth hostile survey, a forged row: with nothing recorded, a success flipped in a shard
was rebuilt into the table, the analysis, the report and the seal without a word, and verify's
sample of 20 episodes per shard missed it. A shard's stamp now records the sha256 of its rows,
every reader refuses a shard that no longer has them, and verify re-simulates every episode
when that fits its time budget. Each test failed before its fix."""

from __future__ import annotations

import json
import shutil
import time
from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
import pytest
from conftest import copy_workflow, edit_config, error_lines, run_snakemake

from mjtrial import provenance
from mjtrial.cli import main
from mjtrial.files.layout import Layout
from mjtrial.verify import Status, verify_results
from mjtrial.verify.recompute import sample_ids

pytestmark = pytest.mark.end_to_end

LAYOUT = Layout.of("research_mode")
N = 24  # more than verify's sample of 20 per shard: a sample can miss a row
SHARD = LAYOUT.shard_table("fast", "00000")


@pytest.fixture(scope="module")
def unrecorded(tmp_path_factory) -> Path:
    """The experiment with N states in one shard per condition, nothing recorded."""
    workdir = copy_workflow(tmp_path_factory.mktemp("unrecorded"))

    def small(config):
        config["states"]["n"] = N
        config["rollout"]["shard_size"] = N
        config["analysis"]["n_resamples"] = 500
        config["recording"]["episodes"] = "none"

    edit_config(workdir, small)
    run_snakemake(workdir)
    return workdir


def forge_row(path: Path, state_id: int, *, restamp: bool) -> None:
    """Flip one episode's success in a shard, keeping its stamp; `restamp`: as a forger who
    knows the stamp's `rows_sha256` would, record the forged rows' hash there."""
    table = pq.read_table(path)
    metadata = dict(table.schema.metadata)
    success = table.column("success").to_pylist()
    success[state_id - table.column("state_id")[0].as_py()] ^= True
    i = table.column_names.index("success")
    table = table.set_column(i, table.schema.field(i), pa.array(success, type=pa.bool_()))
    stamp = json.loads(metadata[provenance.STAMP_KEY.encode()])
    if restamp and "rows_sha256" in stamp["extra"]:
        stamp["extra"]["rows_sha256"] = provenance.rows_sha256(table.replace_schema_metadata(None))
    metadata[provenance.STAMP_KEY.encode()] = json.dumps(stamp).encode()
    pq.write_table(table.replace_schema_metadata(metadata), path)


def copy_of(built: Path, tmp_path: Path) -> Path:
    workdir = tmp_path / "copy"
    shutil.copytree(built, workdir, symlinks=True)
    return workdir


def test_a_table_s_rows_hash_is_the_same_written_and_read_back(tmp_path):
    table = pa.table(
        {
            "state_id": pa.array(np.arange(4)),
            "success": pa.array([True, False, True, True]),
            "peak": pa.array([1.0, np.nan, -0.0, 2.5]),
            "failure_category": pa.array([None, "slipped", None, None], pa.string()),
        }
    )
    pq.write_table(table, tmp_path / "t.parquet")
    back = pq.read_table(tmp_path / "t.parquet")
    assert provenance.rows_sha256(back) == provenance.rows_sha256(table)
    chunked = pa.concat_tables([table.slice(0, 1), table.slice(1)])
    assert provenance.rows_sha256(chunked) == provenance.rows_sha256(table)
    flipped = table.set_column(1, "success", pa.array([True, True, True, True]))
    assert provenance.rows_sha256(flipped) != provenance.rows_sha256(table)
    renamed = table.rename_columns(["state_id", "success", "peak", "other"])
    assert provenance.rows_sha256(renamed) != provenance.rows_sha256(table)


def test_a_shard_s_stamp_records_its_rows(unrecorded):
    path = unrecorded / SHARD
    stamp = provenance.read_stamp(path)
    table = pq.read_table(path).replace_schema_metadata(None)
    assert stamp["extra"]["rows_sha256"] == provenance.rows_sha256(table)


def test_a_flipped_row_is_refused_by_the_gather_not_rebuilt(unrecorded, tmp_path):
    """Survey case 2: `snakemake -c2` rebuilt gather, analysis, report, seal and crate over an
    edited shard without a word."""
    workdir = copy_of(unrecorded, tmp_path)
    table = workdir / LAYOUT.rollout_table("fast")
    before = table.read_bytes()
    forge_row(workdir / SHARD, 3, restamp=False)
    proc = run_snakemake(workdir, check=False)
    assert proc.returncode != 0, proc.stdout
    said = [line for line in error_lines(proc) if "rows_sha256" in line]
    assert said and SHARD.as_posix() in said[0], "\n".join(error_lines(proc))
    assert table.read_bytes() == before  # the condition's table is the honest one still


def test_verify_re_simulates_every_episode_of_a_small_run(unrecorded, tmp_path):
    """Survey case 2: a forged row rebuilt into the results passed `verify --strict` whenever
    the sample of 20 per shard missed it; the N = 24 run now has every episode re-simulated."""
    workdir = copy_of(unrecorded, tmp_path)
    seed = 7
    sampled = sample_ids(0, N, 20, seed=seed, key=SHARD.as_posix())
    missed = next(i for i in range(N) if i not in sampled)
    forge_row(workdir / SHARD, missed, restamp=True)
    run_snakemake(workdir)  # the forger's rebuild: gather, analysis, report, seal, crate
    report = verify_results(
        workdir / LAYOUT.root,
        config_path=workdir / "config" / "config.yaml",
        repo_root=workdir,
        seed=seed,
    )
    tampered = set(report.with_status(Status.TAMPERED))
    assert SHARD.as_posix() in tampered, report.format()
    assert f"re-simulated {2 * N} of {2 * N} episodes" in report.format(), report.format()


def test_diff_names_a_shard_whose_rows_are_not_its_stamp_s(unrecorded, tmp_path, capsys):
    """A forged row with the seal written again over it: the diff's gate names the shard."""
    a = unrecorded / LAYOUT.root
    b = tmp_path / "b"
    shutil.copytree(a, b, symlinks=True)
    rel = SHARD.relative_to(LAYOUT.root)
    forge_row(b / rel, 5, restamp=False)
    seal = json.loads((b / "seal.json").read_text())
    seal["outputs"][SHARD.as_posix()] = provenance.file_sha256(b / rel)
    (b / "seal.json").write_text(json.dumps(seal))
    code = main(["diff", str(a), str(b), "--fail-on", "changed", "--out", str(tmp_path / "d")])
    err = capsys.readouterr().err
    assert code == 1, err
    assert f"rows are not the ones their stamp records in b: {rel.as_posix()}" in err, err


def test_every_episode_when_the_estimate_fits_the_budget_else_a_sample_said_so():
    from mjtrial.verify.coverage import DEFAULT_RESIMULATE, RESIMULATE_ALL, coverage

    def busy(ids):  # 10 ms of CPU per episode
        start = time.process_time()
        while time.process_time() - start < 0.01 * len(ids):
            pass

    found = coverage(1000, range(1000), busy, budget_s=100.0)
    assert found.per_shard == RESIMULATE_ALL and found.why.startswith("every episode, about ")
    found = coverage(1000, range(1000), busy, budget_s=2.0)
    assert found.per_shard == DEFAULT_RESIMULATE
    assert "over the 2 s budget; --resimulate all re-simulates them all" in found.why


def test_one_timed_episode_that_bounds_them_all_within_the_budget_is_the_only_one():
    """The first call loads the model and task as well as running its episode: its time bounds
    an episode's, so within the budget it is the estimate; over it, five episodes are timed to
    take the loading out."""
    from mjtrial.verify.coverage import DEFAULT_RESIMULATE, RESIMULATE_ALL, coverage

    calls = []

    def timed(load_s, episode_s):
        def resimulate(ids):
            calls.append(list(ids))
            start = time.process_time()
            while time.process_time() - start < load_s + episode_s * len(ids):
                pass

        return resimulate

    found = coverage(100, range(100), timed(0.01, 0.01), budget_s=10.0)
    assert found.per_shard == RESIMULATE_ALL and calls == [[0]]
    calls.clear()
    # one call takes 0.2 s: 100 of them would be 20 s, over the budget; the episodes alone fit
    found = coverage(100, range(100), timed(0.19, 0.01), budget_s=10.0)
    assert calls == [[0], [0, 1, 2, 3, 4]]
    assert found.per_shard == RESIMULATE_ALL and found.why.startswith("every episode, about ")
    calls.clear()
    found = coverage(100, range(100), timed(0.0, 0.2), budget_s=10.0)
    assert calls == [[0], [0, 1, 2, 3, 4]] and found.per_shard == DEFAULT_RESIMULATE
