"""The studies end to end: `snakemake -c2 sensitivity | dose_response | studies` on the small
experiment, reusing its nominal rollouts, with a variant that destabilises the simulation."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import pytest
from conftest import edit_config, run_snakemake
from test_pipeline import planned_jobs

from mjtrial import provenance
from mjtrial.crate import validation
from mjtrial.files.layout import Layout
from mjtrial.verify import Status, verify_results

pytestmark = pytest.mark.end_to_end

LAYOUT = Layout.of("research_mode")
VARIANTS = {
    "rk4": {"option": {"integrator": "RK4"}},
    # Gravity a million billion times Earth's: every episode halts at its first step.
    "unstable": {"option": {"gravity": [0, 0, -1e15]}},
}
SWEEP = {"parameter": "lift_time", "values": [0.15, 0.3, 1.5], "margin": 0.05}


def small_studies(config):
    config["variants"] = VARIANTS
    config["sweep"] = SWEEP


@pytest.fixture(scope="module")
def studied(built, tmp_path_factory) -> Path:
    workdir = tmp_path_factory.mktemp("studies") / "copy"
    shutil.copytree(built, workdir, symlinks=True)
    edit_config(workdir, small_studies)
    run_snakemake(workdir, "studies")
    return workdir


def test_studies_reuse_the_nominal_rollouts(built, tmp_path):
    workdir = tmp_path / "copy"
    shutil.copytree(built, workdir, symlinks=True)
    edit_config(workdir, small_studies)
    assert planned_jobs(workdir) == {}  # the built-in experiment is untouched
    sensitivity = planned_jobs_for(workdir, "sensitivity")
    assert "rollout" not in sensitivity and "gather" not in sensitivity
    # 2 variants x the falsifier's 2 conditions, in 3 shards each (12 states in shards of 5)
    assert sensitivity["rollout_variant"] == 2 * 2 * 3
    assert sensitivity["gather_variant"] == 2 * 2
    dose = planned_jobs_for(workdir, "dose_response")
    # 0.3 s only: 0.15 s is fast and 1.5 s is slow
    assert dose["rollout"] == 3 and dose["gather"] == 1


def planned_jobs_for(workdir: Path, *targets: str) -> dict[str, int]:
    from conftest import run_snakemake as run

    out = run(workdir, "-n", *targets).stdout
    if "Nothing to be done" in out:
        return {}
    table = out.split("Job stats:")[1]
    jobs = {}
    for line in table.splitlines()[3:]:
        parts = line.split()
        if len(parts) == 2 and parts[1].isdigit() and parts[0] != "total":
            jobs[parts[0]] = int(parts[1])
        elif jobs and not line.strip():
            break
    return jobs


def test_adding_a_variant_runs_only_its_episodes(studied, tmp_path):
    workdir = tmp_path / "copy"
    shutil.copytree(studied, workdir, symlinks=True)
    edit_config(workdir, lambda c: c["variants"].update(cone={"option": {"cone": "pyramidal"}}))
    jobs = planned_jobs_for(workdir, "sensitivity")
    assert jobs == {
        "rollout_variant": 2 * 3,  # the falsifier's 2 conditions, 3 shards each
        "gather_variant": 2,
        "study_sensitivity": 1,
        "seal_study": 1,
        "crate": 1,
        "sensitivity": 1,
    }


def test_sensitivity_judges_every_variant_and_an_unstable_one_is_invalid(studied):
    summary = json.loads((studied / LAYOUT.study_summary("sensitivity")).read_text())
    records = summary["variants"]
    assert list(records) == ["nominal", "rk4", "unstable"]
    nominal_summary = json.loads((studied / LAYOUT.summary).read_text())
    # The nominal row is the built-in experiment's own result.
    assert records["nominal"]["paired_difference"]["estimate"] == pytest.approx(
        nominal_summary["paired_difference"]["estimate"]
    )
    unstable = records["unstable"]
    assert unstable["verdict"] == "invalid"
    assert unstable["unhealthy"] == 2 * 12
    assert records["rk4"]["verdict"] in ("survives", "refuted")
    assert records["rk4"]["overrides"] == VARIANTS["rk4"]
    assert len(records["rk4"]["model_sha256"]) == 64
    assert records["rk4"]["model_sha256"] != records["nominal"]["model_sha256"]
    assert summary["verdicts"]["invalid"] == 1


def test_dose_response_covers_the_sweep_on_the_same_states(studied):
    summary = json.loads((studied / LAYOUT.study_summary("dose_response")).read_text())
    assert summary["values"] == [0.15, 0.3, 1.5]
    assert all(row["n"] == 12 for row in summary["per_value"])
    # 0.15 s and 1.5 s are the built-in fast and slow rollouts.
    fast = json.loads((studied / LAYOUT.summary).read_text())["conditions"]["fast"]
    assert summary["per_value"][0]["successes"] == fast["successes"]


def test_study_outputs_are_stamped_reported_sealed_and_verified(studied, tmp_path):
    for study in ("sensitivity", "dose_response"):
        for path in [
            LAYOUT.study_summary(study),
            LAYOUT.study_report(study),
            *LAYOUT.study_figure_files(study),
            LAYOUT.study_seal(study),
        ]:
            assert provenance.read_stamp(studied / path)["rule"].split(":")[0] in (
                study,
                "seal",
            )
    # A variant's rollouts: its shards, then the gathered table, stamped with its qualified rule.
    for shard in ("00000", "00001", "00002"):
        for path in (
            LAYOUT.shard_table("fast", shard, "rk4"),
            LAYOUT.shard_recordings("fast", shard, "rk4"),
        ):
            assert provenance.read_stamp(studied / path)["rule"] == f"rollout:rk4/fast#{shard}"
    assert provenance.read_stamp(studied / LAYOUT.rollout_table("fast", "rk4"))["rule"] == (
        "gather:rk4/fast"
    )
    sealed = json.loads((studied / LAYOUT.study_seal("sensitivity")).read_text())["outputs"]
    assert (LAYOUT.shard_table("slow", "00002", "unstable")).as_posix() in sealed
    assert (LAYOUT.shard_recordings("slow", "00002", "unstable")).as_posix() in sealed
    assert "## Sensitivity" in (studied / LAYOUT.study_report("sensitivity")).read_text()
    assert "## Dose-response" in (studied / LAYOUT.study_report("dose_response")).read_text()
    report = verify_results(
        studied / LAYOUT.root, config_path=studied / "config" / "config.yaml", repo_root=studied
    )
    assert report.ok, report.format()
    work = tmp_path / "copy"  # edited in a copy: the other tests read `studied` as built
    shutil.copytree(studied, work, symlinks=True)
    figure = work / LAYOUT.study_figure_files("sensitivity")[1]  # the SVG
    figure.write_text(figure.read_text().replace("<svg", "<svg data-x='1'", 1))
    report = verify_results(
        work / LAYOUT.root, config_path=work / "config" / "config.yaml", repo_root=work
    )
    rel = (LAYOUT.study_figure_files("sensitivity")[1]).as_posix()
    assert report[rel].status is Status.TAMPERED


def test_the_crate_covers_the_studies_and_validates_offline(studied, tmp_path):
    crate = studied / LAYOUT.crate
    stamp = provenance.read_stamp(crate)
    assert [r["path"] for r in stamp["inputs"]["seals"]] == [
        LAYOUT.seal.as_posix(),
        LAYOUT.study_seal("sensitivity").as_posix(),
        LAYOUT.study_seal("dose_response").as_posix(),
    ]
    entities = {e["@id"]: e for e in json.loads(crate.read_text())["@graph"]}
    jobs = {e["name"] for i, e in entities.items() if i.startswith("#job/")}
    assert {"sensitivity", "dose_response", "seal:sensitivity", "seal:dose_response"} <= jobs
    assert {f"rollout:unstable/slow#{s}" for s in ("00000", "00001", "00002")} <= jobs
    assert "rollout:lift_time-0.3#00000" in jobs  # the sweep's own value
    sealed = json.loads((studied / LAYOUT.study_seal("sensitivity")).read_text())["outputs"]
    for path, sha in sealed.items():
        rel = path.removeprefix(LAYOUT.root.as_posix() + "/")
        entity = entities.get(rel) or entities[rel + "/"]
        assert entity["sha256"] == sha
    findings = validation.validate(studied / LAYOUT.root, cache_path=tmp_path / "cache" / "http")
    assert findings == [], "\n".join(f.line() for f in findings)


def test_the_studies_stay_out_of_snakemake_c2_after_they_ran(studied, tmp_path):
    """The crate reads an earlier study's seal as it is (`before_update`): a change to what the
    studies depend on reruns the built-in experiment and its crate, never a study."""
    workdir = tmp_path / "copy"
    shutil.copytree(studied, workdir, symlinks=True)
    # nothing to do for the default target nor the studies: one dry run of both
    assert planned_jobs_for(workdir, "all", "studies") == {}
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
    jobs = planned_jobs_for(workdir, "sensitivity")
    assert jobs["study_sensitivity"] == 1 and jobs["crate"] == 1
    assert "rollout_variant" not in jobs  # the analysis settings are not a rollout's
