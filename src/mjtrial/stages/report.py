"""The report stage: the figures and `report.md`, every number formatted from the inputs."""

from __future__ import annotations

import json
import logging
from collections.abc import Mapping
from pathlib import Path
from typing import Any

from mjtrial import REPO_ROOT, report
from mjtrial.stages.stamping import make_stage_stamp, model_inputs

log = logging.getLogger("mjtrial")


def write_report_stage(
    *,
    config: Mapping[str, Any],
    summary_path: Path,
    manifest_path: Path,
    states_path: Path,
    rollout_tables: Mapping[str, Path],
    model_file: Path,
    figures_dir: Path,
    output: Path,
    repo_root: Path = REPO_ROOT,
) -> list[Path]:
    """Draw the figures and write `report.md`; every number in them comes from the inputs."""
    inputs = {
        "summary": summary_path,
        "manifest": manifest_path,
        "states": states_path,
        **model_inputs(model_file),
        **{f"rollout:{k}": v for k, v in rollout_tables.items()},
    }
    stamp = make_stage_stamp("report", dict(config), inputs, repo_root=repo_root)
    summary = json.loads(Path(summary_path).read_text())
    figures = report.write_figures(
        summary=summary,
        states_path=states_path,
        rollout_tables=rollout_tables,
        model_file=model_file,
        lift_times={name: float(c["lift_time"]) for name, c in config["conditions"].items()},
        out_dir=figures_dir,
        stamp=stamp,
    )
    report.write_report(
        summary_path=summary_path,
        config=dict(config),
        manifest_path=manifest_path,
        figure_paths=figures,
        output=output,
        stamp=stamp,
        repo_root=repo_root,
    )
    log.info("report -> %s (%d figure files)", output, len(figures))
    return figures
