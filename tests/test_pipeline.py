"""End to end: a small copy of the experiment run by Snakemake itself.

Checks that a second run has nothing to do, that changing one config value reruns exactly the
stages that depend on it (by Snakemake's own dry run), and that every output is stamped.
Bad input is covered in test_trust.py.
"""

from __future__ import annotations

import json
import re
import shutil
from pathlib import Path

import pyarrow as pa
import pyarrow.parquet as pq
import pytest
import yaml
from conftest import edit_config
from conftest import run_snakemake as run

from mjtrial import provenance

pytestmark = pytest.mark.end_to_end


def planned_jobs(workdir: Path, env: dict | None = None) -> dict[str, int]:
    """Rules and job counts that a dry run would execute, from Snakemake's job stats table."""
    out = run(workdir, "-n", env=env).stdout
    if "Nothing to be done" in out:
        return {}
    table = out.split("Job stats:")[1]
    jobs = {}
    for line in table.splitlines()[3:]:
        m = re.match(r"^(\w+)\s+(\d+)$", line.strip())
        if m and m.group(1) != "total":
            jobs[m.group(1)] = int(m.group(2))
        elif jobs and not line.strip():
            break
    return jobs


# The small experiment's 12 states in shards of 5 (conftest): states [0, 5), [5, 10), [10, 12).
SHARDS = {"00000": range(0, 5), "00001": range(5, 10), "00002": range(10, 12)}


def test_builds_everything_and_second_run_has_nothing_to_do(built):
    results = built / "results" / "research_mode"
    for rel in (
        "states.parquet",
        "rollouts/fast.parquet",
        "rollouts/slow.parquet",
        "rollouts/fast/shard-00000.parquet",
        "rollouts/slow/shard-00002.parquet",
        "analysis/summary.json",
        "manifest.json",
        "rollouts/fast/shard-00000/fast-state-000000.rrd",
        "rollouts/slow/shard-00002/slow-state-000011.rrd",
        "rollouts/slow/shard-00001/blueprint.rbl",
        "replay/failures.rrd",
        "replay/failures.parquet",
        "report.md",
        "figures/sample_traces.svg",
    ):
        assert (results / rel).is_file(), rel
    for condition in ("fast", "slow"):
        folder = results / "rollouts" / condition
        # Each shard: a table of its rows, a folder of one .rrd per episode and its blueprint.
        assert sorted(p.name for p in folder.iterdir()) == sorted(
            [f"shard-{s}" for s in SHARDS] + [f"shard-{s}.parquet" for s in SHARDS]
        )
        for shard, ids in SHARDS.items():
            rows = pq.read_table(folder / f"shard-{shard}.parquet").column("state_id").to_pylist()
            assert rows == list(ids)
            assert sorted(p.name for p in (folder / f"shard-{shard}").glob("*.rrd")) == [
                f"{condition}-state-{i:06d}.rrd" for i in ids
            ]
            assert (folder / f"shard-{shard}" / "blueprint.rbl").is_file()
        # The condition's table is its shards' rows, in state order.
        whole = pq.read_table(results / "rollouts" / f"{condition}.parquet")
        parts = [pq.read_table(folder / f"shard-{s}.parquet") for s in SHARDS]
        assert whole.replace_schema_metadata(None).equals(
            pa.concat_tables([t.replace_schema_metadata(None) for t in parts])
        )
    assert planned_jobs(built) == {}


def test_every_output_is_stamped_with_commit_state_and_versions(built):
    results = built / "results" / "research_mode"
    folders = [results / "rollouts" / c / f"shard-{s}" for c in ("fast", "slow") for s in SHARDS]
    folders.append(results / "source")  # the crate's copy of the sources
    outputs = [
        p
        for p in results.rglob("*")
        if (p.is_file() and "logs" not in p.parts and not any(f in p.parents for f in folders))
        or p in folders
    ]
    # 15 data files (states, 2 tables, 2 nominal episodes, 6 shard tables, failures.rrd and
    # .parquet, summary, manifest), 6 folders of recordings, report.md, 5 figures as PNG and SVG,
    # the seal, the crate and its copy of the sources
    assert len(outputs) == 36  # with the registration
    for path in [*outputs, *(p for f in folders for p in f.glob("*.rrd"))]:
        stamp = provenance.read_stamp(path)
        assert stamp["versions"]["mujoco"] == "3.14.0"
        # The copy is not a git repository: the stamp says so instead of crashing.
        assert stamp["git"]["available"] is False and stamp["git"]["reason"]
    rollout = provenance.read_stamp(results / "rollouts" / "fast.parquet")
    assert rollout["rule"] == "gather:fast"
    assert rollout["inputs"]["model"]["sha256"] == provenance.file_sha256(
        built / "models" / "gantry_gripper" / "scene.xml"
    )
    config = yaml.safe_load((built / "config" / "config.yaml").read_text())
    condition_slice = {
        "condition": "fast",
        "task": "tasks/gantry_lift/task.py",
        "lift_time": 0.15,
        "failure_taxonomy": config["failure_taxonomy"],
        "recording": {"rate_hz": config["recording"]["rate_hz"], "episodes": "all"},
    }
    assert rollout["config_slice"] == condition_slice
    assert rollout["config_slice_sha256"] == provenance.config_hash(rollout["config_slice"])
    for shard in SHARDS:
        for path in (
            results / "rollouts" / "fast" / f"shard-{shard}.parquet",
            results / "rollouts" / "fast" / f"shard-{shard}",
        ):
            stamp = provenance.read_stamp(path)
            assert stamp["rule"] == f"rollout:fast#{shard}"
            assert stamp["config_slice"] == condition_slice
            assert stamp["inputs"]["states"]["sha256"] == provenance.file_sha256(
                results / "states.parquet"
            )
    failures = provenance.read_stamp(results / "replay" / "failures.parquet")
    assert failures["config_slice"] == {"failures_max": config["recording"]["failures_max"]}
    manifest = json.loads((results / "manifest.json").read_text())
    assert manifest["model"]["integrator"] == "mjINT_IMPLICITFAST"
    assert manifest["results"]["conditions"]["fast"]["n"] == 12
    assert manifest["results"]["falsifier"]["verdict"] in ("survives", "refuted")
    # states, 2 tables, 2 nominal episodes, 6 shard tables, 6 shard folders, failures.rrd and
    # .parquet, summary
    assert len(manifest["stamps"]) == 20


def test_changing_n_resamples_reruns_analysis_and_what_follows_only(built, tmp_path):
    workdir = tmp_path / "copy"
    shutil.copytree(built, workdir, symlinks=True)
    edit_config(workdir, lambda c: c["analysis"].update(n_resamples=600))
    assert planned_jobs(workdir) == {
        "all": 1,
        "analysis": 1,
        "figures": 1,
        "manifest": 1,
        "report": 1,
        "seal": 1,
        "crate": 1,
    }


def test_changing_fast_lift_time_reruns_fast_rollout_not_slow(built, tmp_path):
    workdir = tmp_path / "copy"
    shutil.copytree(built, workdir, symlinks=True)
    edit_config(workdir, lambda c: c["conditions"]["fast"].update(lift_time=0.2))
    out = run(workdir, "-n").stdout
    assert planned_jobs(workdir) == {
        "all": 1,
        "analysis": 1,
        "failures": 1,
        "figures": 1,
        "manifest": 1,
        "report": 1,
        "rollout": 3,  # fast's 3 shards
        "gather": 1,
        "seal": 1,
        "crate": 1,
    }
    assert "wildcards: condition=fast" in out and "condition=slow" not in out


def test_touching_files_without_changing_them_reruns_nothing(built, tmp_path):
    workdir = tmp_path / "copy"
    shutil.copytree(built, workdir, symlinks=True)
    for path in [
        workdir / "models" / "gantry_gripper" / "gantry_gripper.xml",
        workdir / "Snakefile",
    ]:
        path.touch()
    assert planned_jobs(workdir) == {}


def test_snakemake_html_report_holds_figures_and_summary(built, tmp_path):
    out = tmp_path / "report.html"
    run(built, "--report", str(out))
    html = out.read_text(errors="replace")
    assert out.stat().st_size > 100_000
    for name in ("success_by_condition.png", "sample_traces.png", "summary.json", "report.md"):
        assert name in html


def test_evaluation_states_come_from_the_evaluation_seed(built):
    from gantry_lift.states import STATE_PARAMETERS

    from mjtrial.design.states import generate_initial_states

    config = yaml.safe_load((built / "config" / "config.yaml").read_text())
    s = config["states"]
    expected = generate_initial_states(
        seed=s["seed"], n=s["n"], ranges=s["ranges"], parameters=STATE_PARAMETERS
    )
    stored = pq.read_table(built / "results" / "research_mode" / "states.parquet")
    assert stored.replace_schema_metadata(None).equals(expected)


def test_editing_the_included_model_file_reruns_both_rollouts(built, tmp_path):
    workdir = tmp_path / "copy"
    shutil.copytree(built, workdir, symlinks=True)
    model = workdir / "models" / "gantry_gripper" / "gantry_gripper.xml"
    model.write_text(model.read_text().replace('forcerange="-18 18"', 'forcerange="-19 19"'))
    jobs = planned_jobs(workdir)
    assert jobs["rollout"] == 2 * 3 and jobs["gather"] == 2 and "states" not in jobs


def test_every_failed_episode_has_exactly_one_category(built):
    from gantry_lift.taxonomy import FailureCategory

    results = built / "results" / "research_mode"
    summary = json.loads((results / "analysis" / "summary.json").read_text())
    names = {c.value for c in FailureCategory}
    for condition in ("fast", "slow"):
        rows = pq.read_table(results / "rollouts" / f"{condition}.parquet").to_pylist()
        failed = [r for r in rows if not r["success"]]
        assert all(r["failure_category"] in names for r in failed)
        assert all(r["failure_category"] is None for r in rows if r["success"])
        counts = summary["failures"][condition]
        assert sum(counts.values()) == len(failed)
        for name in names:
            assert counts[name] == sum(r["failure_category"] == name for r in failed)
