"""The second hostile survey: each case a way the pipeline or `mjtrial verify` was fooled, or
results were lost; each test failed before its fix."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

from conftest import edit_config, run_snakemake

RESULTS = Path("results") / "research_mode"


def copy_of(built: Path, tmp_path: Path) -> Path:
    workdir = tmp_path / "copy"
    shutil.copytree(built, workdir)
    return workdir


def test_mostly_unhealthy_episodes_make_the_main_verdict_invalid(built, tmp_path):
    """Survey case 9: masses up to 1e30 make most episodes "simulation unhealthy"; the main
    falsifier must say invalid, not refuted, and the report must say so."""
    workdir = copy_of(built, tmp_path)

    def heavy(config):
        config["states"]["ranges"]["mass"] = [0.05, 1e30]
        config["analysis"]["bands"]["mass"] = [0.05, 1.0, 1e30]

    edit_config(workdir, heavy)
    run_snakemake(workdir)
    summary = json.loads((workdir / RESULTS / "analysis" / "summary.json").read_text())
    unhealthy = sum(summary["conditions"][c]["unhealthy"] for c in ("fast", "slow"))
    assert unhealthy > 0
    assert summary["falsifier"]["verdict"] == "invalid"
    assert f"{unhealthy} of 24 episodes unhealthy" in summary["falsifier"]["reason"]
    assert "Verdict: **INVALID**" in (workdir / RESULTS / "report.md").read_text()
