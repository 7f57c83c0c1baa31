"""Planned comparisons through the workflow: a third condition planned against the baseline
is tested, reported and drawn, verify recomputes the summary, and a registration read by the
analysis marks an unplanned comparison exploratory, which verify recomputes too."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import pytest
import yaml
from conftest import edit_config, run_snakemake
from scipy.stats import binomtest
from statsmodels.stats.multitest import multipletests

from mjtrial.design.registration import register
from mjtrial.files.layout import Layout
from mjtrial.stages.analysis import run_analysis
from mjtrial.stages.stamping import config_slice
from mjtrial.verify import verify_results
from mjtrial.verify.recompute import recompute

pytestmark = pytest.mark.end_to_end

LAYOUT = Layout.of("research_mode")


@pytest.fixture(scope="module")
def three(built, tmp_path_factory) -> Path:
    """The small built experiment with a third condition, `medium` (a 0.5 s lift), planned
    against `fast` as the falsifier's `slow` is."""
    workdir = tmp_path_factory.mktemp("three") / "copy"
    shutil.copytree(built, workdir, symlinks=True)

    def medium(config):
        config["conditions"]["medium"] = {"lift_time": 0.5}
        config["analysis"]["comparisons"] = {"against": "fast"}

    edit_config(workdir, medium)
    # planned from the start: the copy's registration (of the two-condition design) goes, and
    # the run registers this design
    for name in ("registration.json", "deviations.json"):
        (workdir / LAYOUT.root / name).unlink(missing_ok=True)
    run_snakemake(workdir)
    return workdir


def _verified(workdir: Path):
    return verify_results(
        workdir / LAYOUT.root,
        config_path=workdir / "config" / "config.yaml",
        repo_root=workdir,
        resimulate=1,
        seed=3,
    )


def test_a_planned_comparison_is_tested_reported_drawn_and_verified(three):
    summary = json.loads((three / LAYOUT.summary).read_text())
    pairs = [(c["treatment"], c["baseline"]) for c in summary["comparisons"]]
    assert pairs == [("slow", "fast"), ("medium", "fast")]
    raw = []
    for c in summary["comparisons"]:
        only_t, only_b = (c["table"][f"only_{c[k]}"] for k in ("treatment", "baseline"))
        assert c["mcnemar"]["p_value"] == pytest.approx(
            binomtest(only_t, only_t + only_b, 0.5).pvalue if only_t + only_b else 1.0,
            rel=1e-12,
        )
        raw.append(c["mcnemar"]["p_value"])
    holm = multipletests(raw, method="holm")[1]
    assert [c["mcnemar"]["p_holm"] for c in summary["comparisons"]] == pytest.approx(list(holm))
    report = (three / LAYOUT.report).read_text()
    assert "### Planned comparisons" in report and "| medium - fast | secondary |" in report
    assert "Holm step-down" in report
    assert (three / LAYOUT.figure("paired_outcomes", "png")).is_file()
    result = _verified(three)
    assert result.ok, result.format()


def test_a_comparison_the_registration_did_not_plan_is_exploratory_and_verified(three, tmp_path):
    workdir = tmp_path / "registered"
    shutil.copytree(three, workdir, symlinks=True)
    config = yaml.safe_load((workdir / "config" / "config.yaml").read_text())
    layout = Layout(workdir / LAYOUT.root)
    registration = layout.registration
    # registered anew, as if the design had planned no comparison beyond the falsifier's
    unplanned = {**config, "analysis": {**config["analysis"], "comparisons": []}}
    register(unplanned, layout=layout, repo_root=workdir, again=True, reason="a test")
    conditions = list(config["conditions"])
    run_analysis(
        states_path=workdir / LAYOUT.states,
        rollout_tables={c: workdir / LAYOUT.rollout_table(c) for c in conditions},
        nominal_files={c: workdir / LAYOUT.nominal_episode(c) for c in conditions},
        analysis_slice=config_slice("analysis", config),
        output=workdir / LAYOUT.summary,
        repo_root=workdir,
        registration_path=registration,
    )
    summary = json.loads((workdir / LAYOUT.summary).read_text())
    assert [c["exploratory"] for c in summary["comparisons"]] == [False, True]
    assert "registration" in summary["provenance"]["inputs"]
    # verify recomputes the summary with the registration its stamp records
    found = recompute(
        Layout(workdir / LAYOUT.root),
        config,
        repo_root=workdir,
        current=[LAYOUT.summary.as_posix()],
        resimulate=0,
        seed=1,
    )
    assert (found.recomputed, found.differs) == (1, {})
    # without it, the recomputation would differ: the hook is what makes it equal
    registration.unlink()
    found = recompute(
        Layout(workdir / LAYOUT.root),
        config,
        repo_root=workdir,
        current=[LAYOUT.summary.as_posix()],
        resimulate=0,
        seed=1,
    )
    assert "multiple_comparisons.family: 1 -> 2" in found.differs[LAYOUT.summary.as_posix()]
