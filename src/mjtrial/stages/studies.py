"""The studies' stage: the sensitivity or dose-response summary, its figure and its report.

Both read rollout tables only: the nominal model's are the built-in experiment's own, never
run again.
"""

from __future__ import annotations

import json
import logging
import os
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import pyarrow.parquet as pq

from mjtrial import REPO_ROOT, provenance
from mjtrial.files.layout import NOMINAL, STUDY_FIGURES
from mjtrial.recording.divergence import episode_divergence
from mjtrial.recording.read import find_episode_file
from mjtrial.report import studies as study_report
from mjtrial.sim.contacts import describe_contact_changes
from mjtrial.sim.simenv import model_overrides, variant_version
from mjtrial.stages.stamping import make_stage_stamp, model_inputs, task_inputs
from mjtrial.studies.dose_response import summarize_dose_response
from mjtrial.studies.sensitivity import flipped_episodes, summarize_sensitivity
from mjtrial.studies.variants import nominal_model_hash, variant_model
from mjtrial.task import load_task

log = logging.getLogger("mjtrial")


def _columns(path: Path) -> dict[str, Any]:
    table = pq.read_table(path)
    return {c: table.column(c).to_numpy(zero_copy_only=False) for c in table.column_names}


def run_sensitivity(
    *,
    study_slice: Mapping[str, Any],
    tables: Mapping[str, Mapping[str, Path]],
    recordings: Mapping[str, Mapping[str, Sequence[Path]]],
    model_file: Path,
    output: Path,
    report: Path,
    figures_dir: Path,
    repo_root: Path = REPO_ROOT,
) -> dict[str, Any]:
    """The falsifier judged under every variant (`analysis/sensitivity.json`), its forest plot
    and its report.

    Args:
      tables: per variant (`NOMINAL` first), per condition, its rollout table.
      recordings: `mjtrial.sim.simenv.version_recordings`: where the flipped episodes'
        trajectories are read.
    """
    summary = sensitivity_summary(
        study_slice=study_slice, tables=tables, recordings=recordings, model_file=model_file
    )
    inputs = {f"{v}/{c}": p for v, by in tables.items() for c, p in by.items()}
    inputs |= {
        f"{v}/{c}/{Path(f).name}": f
        for v, by in recordings.items()
        for c, folders in by.items()
        for f in folders
    }
    return _write(
        "sensitivity",
        summary,
        study_slice,
        {**inputs, **model_inputs(model_file)},
        output=output,
        report=report,
        figures_dir=figures_dir,
        repo_root=repo_root,
        model_file=model_file,
    )


def run_dose_response(
    *,
    study_slice: Mapping[str, Any],
    states_path: Path,
    tables: Mapping[float, Path],
    output: Path,
    report: Path,
    figures_dir: Path,
    repo_root: Path = REPO_ROOT,
) -> dict[str, Any]:
    """Success against the swept parameter on the same states (`analysis/dose_response.json`),
    its curve and its report.

    Args:
      tables: per swept value, the rollout table of the condition that runs it.
    """
    summary = dose_response_summary(
        study_slice=study_slice, states_path=states_path, tables=tables, repo_root=repo_root
    )
    inputs = {
        "states": states_path,
        **task_inputs(study_slice["task"], repo_root=repo_root),
        **{f"{v:g}": p for v, p in tables.items()},
    }
    return _write(
        "dose_response",
        summary,
        study_slice,
        inputs,
        output=output,
        report=report,
        figures_dir=figures_dir,
        repo_root=repo_root,
    )


def _write(
    study: str,
    summary: dict[str, Any],
    study_slice: Mapping[str, Any],
    inputs: Mapping[str, Any],
    *,
    output: Path,
    report: Path,
    figures_dir: Path,
    repo_root: Path,
    model_file: Path | None = None,
) -> dict[str, Any]:
    stamp = make_stage_stamp(study, dict(study_slice), inputs, repo_root=repo_root)
    provenance.write_json(summary, output, stamp)
    figures = study_report.write_study_figures(
        sensitivity=summary if study == "sensitivity" else None,
        dose_response=summary if study == "dose_response" else None,
        out_dir=figures_dir,
        stamp=stamp,
    )
    text = study_report_text(
        study, summary, report=report, figures_dir=figures_dir, model_file=model_file
    )
    provenance.write_markdown(text, report, stamp)
    log.info("%s -> %s, %s, %d figure files", study, output, report, len(figures))
    return summary


def _divergence(
    recordings: Mapping[str, Mapping[str, Sequence[Path]]],
    variant: str,
    condition: str,
    state_id: int,
) -> dict[str, Any]:
    """Where a flipped episode's trajectories under the nominal model and under `variant`
    part (`episode_divergence`), or why that is not known."""
    files = []
    for side in (NOMINAL, variant):
        folders = recordings.get(side, {}).get(condition, [])
        try:
            files.append(find_episode_file(folders, condition=condition, state_id=state_id))
        except KeyError:  # not recorded (recording.episodes: failed, and it succeeded)
            files.append(None)
    return episode_divergence(files, (NOMINAL, variant), condition=condition, state_id=state_id)


def sensitivity_summary(
    *,
    study_slice: Mapping[str, Any],
    tables: Mapping[str, Mapping[str, Path]],
    recordings: Mapping[str, Mapping[str, Sequence[Path]]],
    model_file: Path,
) -> dict[str, Any]:
    """`analysis/sensitivity.json` from the rollout tables, and for a variant on another
    MuJoCo version, its flipped episodes with where their trajectories part, from
    `recordings` (`mjtrial verify` checks against it)."""
    variants = {}
    for name, by_condition in tables.items():
        overrides = {} if name == NOMINAL else study_slice["variants"][name]
        if name == NOMINAL:
            sha = nominal_model_hash(model_file)
        else:  # a variant naming a MuJoCo version: its edits' model on this MuJoCo
            edits = model_overrides(overrides)
            sha = variant_model(model_file, edits, key_prefix=f"variants.{name}")[1]
        variants[name] = {
            "tables": {c: _columns(p) for c, p in by_condition.items()},
            "overrides": overrides,
            "model_sha256": sha,
        }
    summary = summarize_sensitivity(
        variants, falsifier=study_slice["falsifier"], analysis=study_slice["analysis"]
    )
    for name, record in summary["variants"].items():
        if variant_version(record["overrides"]):
            record["flipped"] = flipped_episodes(
                variants[NOMINAL]["tables"], variants[name]["tables"]
            )
            for episode in record["flipped"]["episodes"]:
                episode["divergence"] = _divergence(
                    recordings, name, episode["condition"], episode["state_id"]
                )
    return summary


def dose_response_summary(
    *,
    study_slice: Mapping[str, Any],
    states_path: Path,
    tables: Mapping[float, Path],
    repo_root: Path = REPO_ROOT,
) -> dict[str, Any]:
    """`analysis/dose_response.json` from the rollout tables (`mjtrial verify` checks against
    it)."""
    sweep = study_slice["sweep"]
    (band_parameter, band_edges), *_ = study_slice["bands"].items()
    task = load_task(study_slice["task"], repo_root=repo_root)
    by_value = {v: _columns(p) for v, p in tables.items()}
    states = _columns(states_path)
    if "stopping" in study_slice:  # a stopping rule ran the first n states only
        n = min(len(t["state_id"]) for t in by_value.values())
        states = {c: values[states["state_id"] < n] for c, values in states.items()}
    summary = summarize_dose_response(
        by_value,
        parameter=sweep["parameter"],
        states=states,
        band_parameter=band_parameter,
        band_edges=band_edges,
        analysis=study_slice["analysis"],
        margin=sweep["margin"],
        reference=sweep.get("reference"),
        toward=sweep.get("toward"),
        units={p: task.unit_of(p) for p in (sweep["parameter"], band_parameter)},
    )
    return summary


def study_report_text(
    study: str,
    summary: Mapping[str, Any],
    *,
    report: Path,
    figures_dir: Path,
    model_file: Path | None = None,
) -> str:
    """A study's report (its figure's PNG linked from the report's folder); with `model_file`,
    the sensitivity report says what each variant's edits of geoms do to their contacts."""
    png = Path(figures_dir) / f"{STUDY_FIGURES[study]}.png"
    figure = Path(os.path.relpath(png, Path(report).parent)).as_posix()
    summary = json.loads(json.dumps(summary))
    if study == "dose_response":
        return study_report.render_dose_response_section(summary, figure=figure) + "\n"
    changes = {}
    if model_file is not None:
        nominal = variant_model(model_file, {})[0]
        for name, rec in summary["variants"].items():
            edits = model_overrides(rec["overrides"])
            if edits:
                edited = variant_model(model_file, edits)[0]
                changes[name] = describe_contact_changes(nominal, edited)
    return (
        study_report.render_sensitivity_section(summary, figure=figure, contact_changes=changes)
        + "\n"
    )
