"""`mjtrial verify`: every output's stamp checked against the files, config, model and code.

End to end on a copy of the small built experiment (one mutation per copy), plus unit tests of
the stale / tampered / missing logic on hand-made stamps.
"""

from __future__ import annotations

import copy
import json
import shutil
from pathlib import Path

import pyarrow as pa
import pyarrow.parquet as pq
import pytest
from conftest import edit_config, run_snakemake

from mjtrial import cli, provenance
from mjtrial.files.layout import STAGES
from mjtrial.stages.stamping import config_slice
from mjtrial.verify import (
    Current,
    Status,
    VerifyReport,
    check_stamps,
    parse_rule,
    verify_results,
)

pytestmark = pytest.mark.end_to_end

RESULTS = "results/research_mode"
SHARDS = ("00000", "00001", "00002")  # the built experiment's 12 states in shards of 5
# Each shard's table and folder of recordings (one output), as rollout:<condition>#<shard> wrote
SHARD_OUTPUTS = [
    f"{RESULTS}/rollouts/{c}/shard-{s}{ext}"
    for c in ("fast", "slow")
    for s in SHARDS
    for ext in (".parquet", "")
]
# What gather:<condition> wrote from them
GATHERED = [
    f"{RESULTS}/rollouts/{c}{ext}"
    for c in ("fast", "slow")
    for ext in (".parquet", ".nominal.json")
]
ROLLOUTS = [*SHARD_OUTPUTS, *GATHERED]
STATES = f"{RESULTS}/states.parquet"
SUMMARY = f"{RESULTS}/analysis/summary.json"
MANIFEST = f"{RESULTS}/manifest.json"
FAILURES = f"{RESULTS}/replay/failures.rrd"
FAILURES_TABLE = f"{RESULTS}/replay/failures.parquet"
REPORT = f"{RESULTS}/report.md"
MODEL = "models/gantry_gripper/scene.xml"


def verify(workdir: Path, **kwargs) -> VerifyReport:
    return verify_results(
        workdir / RESULTS,
        config_path=workdir / "config" / "config.yaml",
        repo_root=workdir,
        **kwargs,
    )


# For a change after the rollouts (a summary, manifest, report or figure), which no episode's
# re-simulation reads: verify without re-simulating (`--resimulate 0`)
AFTER_ROLLOUTS = {"resimulate": 0}


@pytest.fixture
def work(built, tmp_path) -> Path:
    """A private copy of the built experiment, to mutate."""
    workdir = tmp_path / "experiment"
    shutil.copytree(built, workdir, symlinks=True)
    return workdir


def report_outputs(report: VerifyReport) -> list[str]:
    return [o.path for o in report.outputs if o.path.startswith(f"{RESULTS}/figures/")] + [REPORT]


def reasons(report: VerifyReport, path: str) -> str:
    return "; ".join(report[path].reasons)


def assert_ok(report: VerifyReport, paths) -> None:
    bad = {p: report[p].line() for p in paths if report[p].status is not Status.OK}
    assert not bad, bad


# --------------------------------------------------------------------------------------------
# End to end on the built experiment
# --------------------------------------------------------------------------------------------


def test_fresh_build_verifies(built, monkeypatch, capsys):
    report = verify(built)
    folders = {
        built / RESULTS / "rollouts" / c / f"shard-{s}" for c in ("fast", "slow") for s in SHARDS
    }
    folders.add(built / RESULTS / "source")  # the crate's copy of the sources: one output
    stamped = sorted(
        p.relative_to(built).as_posix()
        for p in (built / RESULTS).rglob("*")
        if p in folders
        or (
            p.suffix in (".parquet", ".json", ".md", ".png", ".svg", ".rrd")
            and not any(f in p.parents for f in folders)
        )
    )
    assert sorted(o.path for o in report.outputs) == stamped
    assert {STATES, SUMMARY, MANIFEST, FAILURES, FAILURES_TABLE, REPORT, *ROLLOUTS} <= set(stamped)
    assert len(stamped) == 36  # with the crate, its copy of the sources and the registration
    assert report.ok and report.exit_code == 0, report.format()
    assert report.warnings == () and report.skipped == ()

    # The command, with its defaults: results/<experiment> of config/config.yaml in the cwd.
    monkeypatch.chdir(built)
    assert cli.main(["verify"]) == 0
    lines = capsys.readouterr().out.splitlines()
    assert lines[:-2] == [f"ok  {o.path}" for o in report.outputs]
    assert lines[-2].startswith("checked  recomputed ")
    assert lines[0] == f"ok  {STATES}"
    assert lines[-1].startswith("verified: results/research_mode: ")
    assert f"{len(stamped)} ok, 0 stale, 0 tampered, 0 missing" in lines[-1]


def test_config_change_makes_analysis_and_downstream_stale_then_rebuild_verifies(work, capsys):
    edit_config(work, lambda c: c["analysis"].update(n_resamples=700))
    report = verify(work, **AFTER_ROLLOUTS)
    assert report[SUMMARY].status is Status.STALE
    assert "config slice changed: analysis (analysis.n_resamples: 500 -> 700)" in reasons(
        report, SUMMARY
    )
    for path in [MANIFEST, *report_outputs(report)]:
        assert report[path].status is Status.STALE, path
        assert "input stale: analysis/summary.json" in reasons(report, path)
    assert "config slice changed: manifest" in reasons(report, MANIFEST)
    assert_ok(report, [STATES, *ROLLOUTS, FAILURES, FAILURES_TABLE])
    assert not report.ok and report.exit_code == 1

    args = [str(work / RESULTS), "--config", str(work / "config/config.yaml")]
    assert cli.main(["verify", *args, "--repo-root", str(work), "--resimulate", "0"]) == 1
    out = capsys.readouterr().out
    assert f"stale  {SUMMARY}: config slice changed: analysis" in out
    assert f"ok  {STATES}\n" in out
    assert out.splitlines()[-1].startswith("NOT verified: ")

    run_snakemake(work)
    rebuilt = verify(work)
    assert rebuilt.ok, rebuilt.format()


def test_model_change_makes_rollouts_stale_not_states(work):
    model = work / MODEL
    model.write_text(model.read_text() + "<!-- an edit -->\n")
    report = verify(work)
    for path in SHARD_OUTPUTS:
        assert report[path].status is Status.STALE, path
        assert reasons(report, path) == f"model changed: {MODEL}"
    for path in GATHERED:  # gather reads the model too (the nominal episode), and the shards
        condition = Path(path).name.split(".")[0]
        shards = ", ".join(f"rollouts/{condition}/shard-{s}.parquet" for s in SHARDS)
        assert reasons(report, path) == f"model changed: {MODEL}; input stale: {shards}"
    assert report[STATES].status is Status.OK
    assert report[SUMMARY].status is Status.STALE
    assert "input stale: rollouts/" in reasons(report, SUMMARY)
    assert f"model changed: {MODEL}" in reasons(report, MANIFEST)  # its record of the model
    assert f"model changed: {MODEL}" in reasons(report, REPORT)


def test_states_row_changed_under_its_old_stamp_is_tampered(work):
    path = work / STATES
    stamp = provenance.read_stamp(path)
    table = pq.read_table(path)
    mass = table.column("mass").to_pylist()
    mass[3] += 0.01
    table = table.set_column(table.schema.get_field_index("mass"), "mass", pa.array(mass))
    provenance.write_parquet(table.replace_schema_metadata(None), path, stamp)
    assert provenance.read_stamp(path) == stamp

    report = verify(work)
    assert report[STATES].status is Status.TAMPERED
    why = reasons(report, STATES)
    assert why.startswith(
        "sha256 recorded by rollouts/fast/shard-00000, rollouts/fast/shard-00000.parquet, "
        "rollouts/fast/shard-00001 and 12 more"  # 12 shard outputs, the summary, the manifest
    )
    assert "does not match the file" in why
    for rollout in SHARD_OUTPUTS:
        assert report[rollout].status is Status.STALE
        assert reasons(report, rollout) == "input tampered: states.parquet"
    for rollout in GATHERED:
        assert report[rollout].status is Status.STALE
        assert reasons(report, rollout).startswith("input stale: rollouts/")
    assert report[SUMMARY].status is Status.STALE
    assert report.with_status(Status.TAMPERED) == [STATES]


def test_shard_table_changed_under_its_old_stamp_is_tampered(work):
    shard = f"{RESULTS}/rollouts/fast/shard-00001.parquet"
    path = work / shard
    stamp = provenance.read_stamp(path)
    table = pq.read_table(path)
    heights = table.column("final_height").to_pylist()
    heights[0] += 0.01
    column = table.schema.get_field_index("final_height")
    table = table.set_column(column, "final_height", pa.array(heights))
    provenance.write_parquet(table.replace_schema_metadata(None), path, stamp)

    report = verify(work)
    assert report.with_status(Status.TAMPERED) == [shard]
    why = reasons(report, shard)
    assert why.startswith("its rows are not the ones its stamp records (rows_sha256)")
    assert "sha256 recorded by rollouts/fast.nominal.json, rollouts/fast.parquet" in why
    assert "does not match the file" in why
    for gathered in (f"{RESULTS}/rollouts/fast.parquet", f"{RESULTS}/rollouts/fast.nominal.json"):
        assert reasons(report, gathered) == "input tampered: rollouts/fast/shard-00001.parquet"
    assert_ok(
        report, [STATES, *(p for p in ROLLOUTS if "fast" not in p or "shard" in p and p != shard)]
    )


def test_edited_summary_is_tampered(work):
    path = work / SUMMARY
    summary = json.loads(path.read_text())
    assert "provenance" in summary
    summary["conditions"]["fast"]["successes"] += 1
    path.write_text(json.dumps(summary, indent=2))
    assert provenance.read_stamp(path) == summary["provenance"]

    report = verify(work, **AFTER_ROLLOUTS)
    assert report[SUMMARY].status is Status.TAMPERED
    # the figures drawn from it, the manifest and the report record its sha256
    assert reasons(report, SUMMARY).startswith("sha256 recorded by figures/")
    assert "and 10 more does not match" in reasons(report, SUMMARY)
    assert report[MANIFEST].status is Status.STALE
    assert reasons(report, MANIFEST) == "input tampered: analysis/summary.json"
    assert_ok(report, [STATES, *ROLLOUTS, FAILURES, FAILURES_TABLE])
    assert report.with_status(Status.TAMPERED) == [SUMMARY]


def test_deleted_rollout_is_missing(work, capsys):
    (work / RESULTS / "rollouts" / "slow.parquet").unlink()
    report = verify(work)
    slow = f"{RESULTS}/rollouts/slow.parquet"
    assert report[slow].status is Status.MISSING
    assert report[slow].line() == f"missing  {slow}"
    assert "input missing: rollouts/slow.parquet" in reasons(report, SUMMARY)
    assert "input missing: rollouts/slow.parquet" in reasons(report, MANIFEST)
    # failures.rrd was chosen from the tables: it depends on them too
    assert reasons(report, FAILURES) == "input missing: rollouts/slow.parquet"
    assert reasons(report, FAILURES_TABLE) == "input missing: rollouts/slow.parquet"
    assert_ok(report, [STATES, *[p for p in ROLLOUTS if p != slow]])
    assert report.counts()[Status.MISSING] == 1


def test_deleted_manifest_is_missing(work):
    (work / MANIFEST).unlink()
    report = verify(work, **AFTER_ROLLOUTS)
    assert report[MANIFEST].status is Status.MISSING
    # the figures are drawn without the manifest; the report text reads it
    figures = [p for p in report_outputs(report) if p != REPORT]
    assert_ok(report, [STATES, *ROLLOUTS, FAILURES, FAILURES_TABLE, SUMMARY, *figures])
    assert report[REPORT].status is Status.STALE


@pytest.mark.parametrize(
    ("rel", "output"),
    [
        ("figures/sample_traces.png", "figures/sample_traces.png"),
        ("report.md", "report.md"),
    ],
)
def test_garbled_output_has_no_readable_stamp(work, rel, output):
    path = work / RESULTS / rel
    data = bytearray(path.read_bytes())
    data[: len(data) // 2] = bytes(len(data) // 2)
    path.write_bytes(bytes(data))
    report = verify(work, **AFTER_ROLLOUTS)
    assert report[f"{RESULTS}/{output}"].status is Status.TAMPERED
    assert reasons(report, f"{RESULTS}/{output}").startswith("no readable stamp (")
    assert report.counts()[Status.TAMPERED] == 1


@pytest.mark.parametrize("change", ["garble", "garble the first", "delete", "add"])
def test_any_change_to_a_folder_of_recordings_is_tampering(work, change):
    folder = work / RESULTS / "rollouts" / "slow" / "shard-00001"
    first, *_, last = sorted(folder.glob("*.rrd"))
    if change == "garble":
        last.write_bytes(bytes(len(last.read_bytes())))
    elif change == "garble the first":  # the episode file the folder's stamp was read from
        data = bytearray(first.read_bytes())
        data[: len(data) // 2] = bytes(len(data) // 2)
        first.write_bytes(bytes(data))
    elif change == "delete":
        last.unlink()
    else:
        shutil.copy(last, folder / "slow-state-999999.rrd")
    report = verify(work)
    shard = f"{RESULTS}/rollouts/slow/shard-00001"
    assert report[shard].status is Status.TAMPERED
    assert "sha256 recorded by replay/failures.parquet, replay/failures.rrd" in reasons(
        report, shard
    )
    assert reasons(report, FAILURES) == "input tampered: rollouts/slow/shard-00001"
    assert report.counts()[Status.TAMPERED] == 1


def test_a_figure_of_an_earlier_layout_is_skipped_not_stale(work):
    """An upgrade renamed the report's figures (cube_height -> sample_traces): the old files,
    stamped then, are no output of the run, and verify says so instead of calling them stale."""
    figures = work / RESULTS / "figures"
    shutil.copy(figures / "sample_traces.png", figures / "cube_height.png")
    report = verify(work, **AFTER_ROLLOUTS)
    assert report.ok, report.format()
    assert [s.path for s in report.skipped] == [f"{RESULTS}/figures/cube_height.png"]
    assert "no current report draws" in report.skipped[0].reason


def test_replay_recording_is_skipped_not_failed(work, capsys):
    stamp = provenance.read_stamp(work / STATES) | {"rule": "replay"}
    provenance.write_json({"episode": 1}, work / RESULTS / "replay" / "extra.json", stamp)
    report = verify(work, **AFTER_ROLLOUTS)
    assert report.ok
    assert [s.path for s in report.skipped] == [f"{RESULTS}/replay/extra.json"]
    assert cli.main(["verify", "--repo-root", str(work), "--resimulate", "0"]) == 0
    out = capsys.readouterr().out
    assert f"skipped  {RESULTS}/replay/extra.json: rule 'replay' is not part of the pipeline" in out


def test_bad_config_is_a_usage_error(work, capsys):
    edit_config(work, lambda c: c["states"].update(n=0))
    assert cli.main(["verify", "--repo-root", str(work)]) == 2
    assert "states.n" in capsys.readouterr().err


def _copy_note(shown: str) -> str:
    return (
        f"note     {shown} is a copy of the run recorded as {RESULTS}: checked as it (its files "
        "against its seal and stamps, its recomputations and re-simulations with this "
        "checkout's code, config, model and task); rebuilding or updating it with snakemake "
        f"needs it at {RESULTS}"
    )


def test_a_copy_verifies_as_what_it_is_inside_and_outside_the_repository(
    work, tmp_path, monkeypatch, capsys
):
    """Issue 34 case 12: a copy said "is a copy of the run recorded as ..." (inside the
    repository) or "pass --repo-root" (outside) and checked nothing. Stamps record paths in the
    repository: the copy is checked where its seal says the run was, in a view of the checkout,
    its files against its seal and its re-simulations with the checkout's code."""
    inside = f"{RESULTS}_cp"
    outside = tmp_path / "elsewhere" / "research_mode"
    shutil.copytree(work / RESULTS, work / inside, symlinks=True)
    shutil.copytree(work / RESULTS, outside, symlinks=True)
    monkeypatch.chdir(work)
    for folder, shown in ((inside, inside), (str(outside), outside.as_posix())):
        assert cli.main(["verify", "--strict", folder]) == 0, capsys.readouterr()
        out = capsys.readouterr().out.splitlines()
        assert _copy_note(shown) in out
        assert out[-1].startswith(f"verified: {shown}: 36 outputs: 36 ok")
        checked = next(line for line in out if line.startswith("checked  "))
        assert "re-simulated 24 of 24 episodes" in checked
    assert not (work / inside / "results").exists()  # nothing written into the copy
    assert cli.main(["verify", RESULTS]) == 0  # the original is what it was


def test_a_tampered_copy_is_tampered_not_a_copy_to_go_and_verify_elsewhere(work, tmp_path):
    outside = tmp_path / "elsewhere" / "research_mode"
    shutil.copytree(work / RESULTS, outside, symlinks=True)
    path = outside / "rollouts" / "fast" / "shard-00001.parquet"
    stamp, table = provenance.read_stamp(path), pq.read_table(path)
    success = table.column("success").to_pylist()
    success[0] = not success[0]
    table = table.set_column(table.schema.get_field_index("success"), "success", pa.array(success))
    provenance.write_parquet(table.replace_schema_metadata(None), path, stamp)
    report = verify_results(
        outside, config_path=work / "config" / "config.yaml", repo_root=work, resimulate=5
    )
    assert not report.ok
    assert report.with_status(Status.TAMPERED) == [f"{RESULTS}/rollouts/fast/shard-00001.parquet"]
    assert report.notes[0] == _copy_note(outside.as_posix()).removeprefix("note     ")
    assert verify(work).ok  # the original, in place, is untouched


def test_a_benchmarks_folder_without_its_recorded_config_asks_for_it(tmp_path, capsys):
    """A benchmark's config is recorded in its crate; without one, verify does not check the
    folder against the experiment's default config: it says to give the benchmark's."""
    (tmp_path / "results" / "bench" / "training").mkdir(parents=True)
    assert (
        cli.main(["verify", str(tmp_path / "results" / "bench"), "--repo-root", str(tmp_path)]) == 2
    )
    assert capsys.readouterr().err.splitlines() == [
        f"mjtrial verify: {tmp_path / 'results' / 'bench'} is a benchmark's folder that records "
        "no config file (no ro-crate-metadata.json): give it, --config config/<benchmark>.yaml"
    ]


# --------------------------------------------------------------------------------------------
# Unit tests on hand-made stamps
# --------------------------------------------------------------------------------------------

PREFIX = "results/x/"
CONFIG = {
    "model": "m.xml",
    "task": "tasks/gantry_lift/task.py",
    "states": {"seed": 1, "n": 3},
    "conditions": {"fast": {"lift_time": 0.1}},
    "failure_taxonomy": {"lifted_height": 0.03},
    "recording": {"rate_hz": 100, "episodes": "all", "failures_max": 200},
    "design": {"falsifier": {"treatment": "fast"}, "sample_size": {"target_halfwidth": 0.1}},
    "analysis": {"seed": 2},
}
VERSIONS = {"python": "3.11.7", "mujoco": "3.14.0"}
PLATFORM = {"cpu_model": "CPU A", "cpu_flags_fp": ["avx", "sse"]}
CURRENT = Current(
    config=CONFIG,
    code={stage: {f"workflow/scripts/{stage}.py": "S", "mjtrial.stats": "T"} for stage in STAGES},
    versions=VERSIONS,
    platform=PLATFORM,
)


def stamp(rule: str, time: str, inputs=None, **changes):
    stage, _, qualifier = rule.partition(":")
    condition = qualifier.partition("#")[0]  # rollout:<condition>#<shard>
    slice_ = config_slice(stage, CONFIG, condition=condition or None)
    out = {
        "mjtrial_stamp": 1,
        "rule": rule,
        "created_utc": f"2026-01-01T00:00:{time}Z",
        "git": {"available": True, "commit": "c1", "dirty": False, "diff_sha256": None},
        "versions": dict(VERSIONS),
        "config_slice": slice_,
        "config_slice_sha256": provenance.config_hash(slice_),
        "inputs": {k: {"path": p, "sha256": h} for k, (p, h) in (inputs or {}).items()},
        "platform": dict(PLATFORM),
        "extra": {"code": {f"workflow/scripts/{stage}.py": "S", "mjtrial.stats": "T"}},
    }
    out.update(changes)
    return out


def chain():
    """states -> rollout:fast#00000 (a shard) -> analysis, each recording its input's current
    hash."""
    shas = {"m.xml": "M", f"{PREFIX}s.parquet": "S", f"{PREFIX}r.parquet": "R"}
    stamps = {
        f"{PREFIX}s.parquet": stamp("states", "01"),
        f"{PREFIX}r.parquet": stamp(
            "rollout:fast#00000",
            "02",
            {"states": (f"{PREFIX}s.parquet", "S"), "model": ("m.xml", "M")},
        ),
        f"{PREFIX}a.json": stamp("analysis", "03", {"rollout:fast": (f"{PREFIX}r.parquet", "R")}),
    }
    return stamps, shas


def check(stamps, shas, current=CURRENT, **kwargs):
    return check_stamps(
        stamps, current=current, current_sha256=shas.get, outputs_prefix=PREFIX, **kwargs
    )


def test_parse_rule():
    assert parse_rule("states") == ("states", None)
    assert parse_rule("states:development") == ("states", "development")
    assert parse_rule("rollout:fast#00000") == ("rollout", "fast#00000")
    assert parse_rule("rollout:rk4/fast#00002") == ("rollout", "rk4/fast#00002")
    assert parse_rule("gather:fast") == ("gather", "fast")
    assert parse_rule("gather:rk4/fast") == ("gather", "rk4/fast")
    assert parse_rule("analysis") == ("analysis", None)
    for rule in ("rollout", "gather", "rollout_variant:rk4/fast", "replay", "states:", None, 3):
        assert parse_rule(rule) is None


def test_consistent_chain_is_ok():
    stamps, shas = chain()
    report = check(stamps, shas)
    assert report.ok and report.warnings == ()
    assert [o.path for o in report.outputs] == [
        f"{PREFIX}s.parquet",
        f"{PREFIX}r.parquet",
        f"{PREFIX}a.json",
    ]


def test_changed_input_with_older_stamp_is_tampered_and_downstream_stale():
    stamps, shas = chain()
    shas[f"{PREFIX}s.parquet"] = "S2"
    report = check(stamps, shas)
    assert report.status_of(f"{PREFIX}s.parquet") is Status.TAMPERED
    assert reasons(report, f"{PREFIX}s.parquet").startswith("sha256 recorded by r.parquet ")
    assert reasons(report, f"{PREFIX}r.parquet") == "input tampered: s.parquet"
    assert reasons(report, f"{PREFIX}a.json") == "input stale: r.parquet"


def test_same_second_counts_as_not_rebuilt():
    stamps, shas = chain()
    stamps[f"{PREFIX}s.parquet"]["created_utc"] = stamps[f"{PREFIX}r.parquet"]["created_utc"]
    shas[f"{PREFIX}s.parquet"] = "S2"
    assert check(stamps, shas).status_of(f"{PREFIX}s.parquet") is Status.TAMPERED


def test_input_rebuilt_after_its_consumer_makes_the_consumer_stale():
    stamps, shas = chain()
    shas[f"{PREFIX}s.parquet"] = "S2"
    stamps[f"{PREFIX}s.parquet"]["created_utc"] = "2026-01-01T00:00:09Z"
    report = check(stamps, shas)
    assert report.status_of(f"{PREFIX}s.parquet") is Status.OK
    assert reasons(report, f"{PREFIX}r.parquet") == "input rebuilt after it: s.parquet"
    assert reasons(report, f"{PREFIX}a.json") == "input stale: r.parquet"


def test_model_config_code_and_versions_make_stale():
    stamps, shas = chain()
    report = check(stamps, {**shas, "m.xml": "M2"})
    assert reasons(report, f"{PREFIX}r.parquet") == "model changed: m.xml"
    assert report.status_of(f"{PREFIX}s.parquet") is Status.OK

    config = copy.deepcopy(CONFIG)
    config["conditions"]["fast"]["lift_time"] = 0.2
    report = check(stamps, shas, Current(config, CURRENT.code, VERSIONS, PLATFORM))
    assert reasons(report, f"{PREFIX}r.parquet") == (
        "config slice changed: rollout:fast#00000 (lift_time: 0.1 -> 0.2)"
    )
    assert reasons(report, f"{PREFIX}a.json").startswith(
        "config slice changed: analysis (conditions.fast.lift_time: 0.1 -> 0.2); input stale"
    )
    del config["conditions"]["fast"]
    report = check(stamps, shas, Current(config, CURRENT.code, VERSIONS, PLATFORM))
    assert "condition 'fast' is not in the config" in reasons(report, f"{PREFIX}r.parquet")

    code = {**CURRENT.code, "analysis": {"workflow/scripts/analysis.py": "S", "mjtrial.stats": "U"}}
    report = check(stamps, shas, Current(CONFIG, code, VERSIONS, PLATFORM))
    assert reasons(report, f"{PREFIX}a.json") == "code changed: mjtrial.stats"
    assert report.with_status(Status.STALE) == [f"{PREFIX}a.json"]

    versions = {**VERSIONS, "mujoco": "3.15.0"}
    report = check(stamps, shas, Current(CONFIG, CURRENT.code, versions, PLATFORM))
    assert reasons(report, f"{PREFIX}s.parquet") == "versions changed: mujoco 3.14.0 -> 3.15.0"


def test_edited_stamp_slice_is_tampered():
    stamps, shas = chain()
    stamps[f"{PREFIX}s.parquet"]["config_slice"] = {"seed": 9, "n": 3}
    report = check(stamps, shas)
    assert report.status_of(f"{PREFIX}s.parquet") is Status.TAMPERED
    assert "config_slice_sha256 does not match" in reasons(report, f"{PREFIX}s.parquet")


def test_disagreeing_stamps_and_other_platform_warn_only():
    stamps, shas = chain()
    stamps[f"{PREFIX}a.json"]["git"] = {"available": True, "commit": "c2", "diff_sha256": "d"}
    stamps[f"{PREFIX}r.parquet"]["versions"] = {**VERSIONS, "mujoco": "3.13.0"}
    report = check(stamps, shas)
    assert any(w.startswith("stamps disagree on the git state: ") for w in report.warnings)
    assert any(w.startswith("stamps disagree on mujoco: 3.14.0 (2:") for w in report.warnings)
    assert reasons(report, f"{PREFIX}r.parquet") == "versions changed: mujoco 3.13.0 -> 3.14.0"
    assert report.status_of(f"{PREFIX}a.json") is Status.STALE  # through r.parquet only

    stamps, shas = chain()
    here = {"cpu_model": "CPU B", "cpu_flags_fp": ["avx", "avx2", "sse"]}
    report = check(stamps, shas, Current(CONFIG, CURRENT.code, VERSIONS, here))
    assert report.ok
    (warning,) = report.warnings
    assert warning.startswith("platform differs from this machine: cpu_model 'CPU A' (here")
    assert "+avx2" in warning
    assert "warning  platform differs" in report.format()


def test_missing_from_manifest_and_from_references():
    stamps, shas = chain()
    del stamps[f"{PREFIX}s.parquet"], shas[f"{PREFIX}s.parquet"]
    manifest = {"stamps": {f"{PREFIX}s.parquet": {}, f"{PREFIX}gone.json": {}}}
    report = check(stamps, shas, manifest=manifest, manifest_path=f"{PREFIX}manifest.json")
    assert set(report.with_status(Status.MISSING)) == {
        f"{PREFIX}s.parquet",
        f"{PREFIX}gone.json",
        f"{PREFIX}manifest.json",
    }
    assert reasons(report, f"{PREFIX}r.parquet") == "input missing: s.parquet"

    report = check(stamps, shas)  # no manifest: what the stamps reference
    assert report.with_status(Status.MISSING) == [f"{PREFIX}s.parquet"]


def test_unreadable_and_restamped_outputs_are_tampered():
    stamps, shas = chain()
    del stamps[f"{PREFIX}s.parquet"]
    report = check(stamps, shas, unreadable={f"{PREFIX}s.parquet": "no stamp"})
    assert reasons(report, f"{PREFIX}s.parquet") == "no readable stamp (no stamp)"
    assert reasons(report, f"{PREFIX}r.parquet") == "input tampered: s.parquet"

    stamps, shas = chain()
    stamps[f"{PREFIX}s.parquet"]["rule"] = "replay"
    stamps[f"{PREFIX}other.rrd"] = {**stamp("states", "01"), "rule": "replay"}
    report = check(stamps, shas)
    assert report.status_of(f"{PREFIX}s.parquet") is Status.TAMPERED
    assert [s.path for s in report.skipped] == [f"{PREFIX}other.rrd"]
