"""The report's stages: its figures, then `report.md`, every number formatted from the inputs."""

from __future__ import annotations

import json
import logging
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

from mjtrial import REPO_ROOT, report
from mjtrial.design.conditions import model_edits, policy_path
from mjtrial.sim.physics import load_model
from mjtrial.stages.condition import condition_task
from mjtrial.stages.stamping import make_stage_stamp, model_inputs, task_inputs
from mjtrial.task import BoundTask, load_task

log = logging.getLogger("mjtrial")


def write_figures_stage(
    *,
    config: Mapping[str, Any],
    summary_path: Path,
    rollout_tables: Mapping[str, Path],
    shard_folders: Mapping[str, Sequence[Path]],
    model_file: Path,
    figures_dir: Path,
    repo_root: Path = REPO_ROOT,
) -> list[Path]:
    """Draw the report's figures from the summary, the tables and the recordings.

    A job of their own, apart from `report.md`: they need neither the manifest nor the failures
    gathered, so they are drawn while the failures job runs (at N = 200 each takes 1-2 s, and
    the report waited for both one after the other). `shard_folders` (condition -> its shards'
    folders of recordings, as the layout names them for this run, none without recordings) hold
    the sample traces drawn: a folder an earlier run left is never read.
    """
    inputs = {
        "summary": summary_path,
        **model_inputs(model_file),
        **task_inputs(config["task"], repo_root=repo_root),
        **{f"rollout:{k}": v for k, v in rollout_tables.items()},
        **{
            f"recordings:{k}": [p for p in shard_folders[k] if Path(p).is_dir()]
            for k in shard_folders
        },
    }
    stamp = make_stage_stamp("figures", dict(config), inputs, repo_root=repo_root)
    summary = json.loads(Path(summary_path).read_text())
    bound = BoundTask.of(load_task(config["task"], repo_root=repo_root), load_model(model_file))
    figures = report.write_figures(
        summary=summary,
        bound=bound,
        rollout_tables=rollout_tables,
        recordings=shard_folders,
        conditions=config["conditions"],
        out_dir=figures_dir,
        stamp=stamp,
        condition_bounds=_own_bounds(config, model_file, repo_root=repo_root),
    )
    log.info("figures -> %s (%d files)", figures_dir, len(figures))
    return figures


def write_report_stage(
    *,
    config: Mapping[str, Any],
    summary_path: Path,
    manifest_path: Path,
    figure_paths: Sequence[Path],
    model_file: Path,
    output: Path,
    repo_root: Path = REPO_ROOT,
) -> None:
    """Write `report.md`; every number in it comes from the inputs, and it shows the figures
    (`write_figures_stage`). `model_file` is the model the report describes (checked against
    the manifest's hash)."""
    inputs = {
        "summary": summary_path,
        "manifest": manifest_path,
        "figures": list(figure_paths),
        **model_inputs(model_file),
        **task_inputs(config["task"], repo_root=repo_root),
    }
    stamp = make_stage_stamp("report", dict(config), inputs, repo_root=repo_root)
    manifest = json.loads(Path(manifest_path).read_text())
    if load_model(model_file).opt.timestep != manifest["model"]["timestep"]:
        raise ValueError(f"{model_file}: its timestep differs from the manifest's")
    report.write_report(
        summary_path=summary_path,
        config=dict(config),
        manifest_path=manifest_path,
        figure_paths=figure_paths,
        output=output,
        stamp=stamp,
        repo_root=repo_root,
    )
    log.info("report -> %s", output)


def _own_bounds(
    config: Mapping[str, Any], model_file: Path, *, repo_root: Path
) -> dict[str, BoundTask]:
    """The conditions that edit the model or name a policy file, each on what it ran (its
    timestep sets its episodes' steps and time axis)."""
    return {
        name: condition_task(
            {"condition": name, "task": config["task"], **condition},
            model_file,
            repo_root=repo_root,
        )
        for name, condition in config["conditions"].items()
        if model_edits(condition) or policy_path(condition)
    }
