"""The manifest stage: the reproducibility record and the stamp of every output."""

from __future__ import annotations

import json
import logging
import os
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import mujoco

# recording: the reader of the .rrd stamps this stage reads is part of its code (its hash)
from mjtrial import REPO_ROOT, provenance, recording  # noqa: F401
from mjtrial.design.conditions import model_edits
from mjtrial.design.registration import deviations_seen, manifest_section
from mjtrial.design.registration import read as read_registration
from mjtrial.design.states import distribution
from mjtrial.files.layout import CONFIG_FILE, Layout
from mjtrial.sim.physics import compiled_sha256, load_model
from mjtrial.stages.stamping import make_stage_stamp
from mjtrial.stages.states import EVALUATION_RULE, REDRAWN
from mjtrial.studies.variants import variant_model
from mjtrial.task import load_task

log = logging.getLogger("mjtrial")


def write_manifest(
    *,
    config: Mapping[str, Any],
    summary_path: Path,
    outputs: Sequence[Path],
    model_file: Path,
    output: Path,
    command_line: Mapping[str, Any] | None = None,
    command: str = "snakemake -c2",
    config_file: str = CONFIG_FILE,
    repo_root: Path = REPO_ROOT,
    registration: Path | None = None,
) -> dict[str, Any]:
    """Gather the reproducibility record and the stamp of every output into `manifest.json`.

    `config_file` is the run's config file (config/config.yaml, or a --configfile naming an
    experiment), `command_line` the config values the run was given on top of it with
    `--config` or `--configfile`; `command` is the command that ran them
    (`mjtrial.config.rerun_command`).
    """
    manifest, inputs = manifest_record(
        config=config,
        command_line=command_line or {},
        command=command,
        config_file=config_file,
        summary_path=summary_path,
        outputs=outputs,
        model_file=model_file,
        repo_root=repo_root,
        registration=registration,
    )
    stamp = make_stage_stamp("manifest", dict(config), inputs, repo_root=repo_root)
    provenance.write_json(manifest, output, stamp)
    log.info("manifest -> %s", output)
    return manifest


def condition_edits(config: Mapping[str, Any], model_file: Path) -> dict[str, Any]:
    """Per condition that edits the model: its edits and its compiled model's sha256, which
    differs from the committed model's (`compiled_sha256`) where the model does."""
    out = {}
    for name, condition in config["conditions"].items():
        edits = model_edits(condition)
        if edits:
            key = f"conditions.{name}.model"
            _, sha256 = variant_model(model_file, {}, key_prefix=key, then=[(edits, key)])
            out[name] = {"edits": edits, "compiled_sha256": sha256}
    return out


def manifest_record(
    *,
    config: Mapping[str, Any],
    summary_path: Path,
    outputs: Sequence[Path],
    model_file: Path,
    command_line: Mapping[str, Any],
    command: str,
    config_file: str = CONFIG_FILE,
    repo_root: Path = REPO_ROOT,
    registration: Path | None = None,
) -> tuple[dict[str, Any], dict[str, Path]]:
    """The manifest the stage writes and its stamp's inputs (`mjtrial verify` checks
    `manifest.json` against it); `registration`: the registered design's file, when there is
    one (`mjtrial.design.registration`), recorded with the run's deviations from it."""
    model = load_model(model_file)
    summary = json.loads(Path(summary_path).read_text())

    def rel(path: Path) -> str:
        return provenance.repo_relative(path, repo_root)

    stamps = {rel(p): provenance.read_stamp(p) for p in [*outputs, summary_path]}
    manifest = {
        "experiment": config["experiment"],
        "design": config["design"],
        "rerun": {
            "command": command,
            "config_file": config_file,
            "config": dict(config),
            "command_line": dict(command_line),
            "commit": next(iter(stamps.values()))["git"].get("commit"),
        },
        "versions": provenance.library_versions(),
        "model": {
            "path": config["model"],
            "sha256": provenance.model_sha256(model_file),
            "files": {
                Path(os.path.relpath(p, model_file.parent)).as_posix(): provenance.file_sha256(p)
                for p in provenance.model_files(model_file)
            },
            "timestep": model.opt.timestep,
            "integrator": mujoco.mjtIntegrator(model.opt.integrator).name,
            "cone": mujoco.mjtCone(model.opt.cone).name,
            "impratio": model.opt.impratio,
            "compiled_sha256": compiled_sha256(model),
            "condition_edits": condition_edits(config, model_file),
        },
        "seeds": {
            "states": config["states"]["seed"],
            "development": config["states"]["development_seed"],
            "bootstrap": config["analysis"]["seed"],
        },
        "task": task_record(config, repo_root=repo_root),
        "n_states": config["states"]["n"],
        "randomization_ranges": config["states"]["ranges"],
        "state_distributions": {
            name: distribution(
                name, config["states"]["ranges"], config["states"].get("distributions")
            )
            for name in config["states"]["ranges"]
        },
        "success_definition": load_task(config["task"], repo_root=repo_root).success_text
        or "the task's success test",
        "results": {
            "conditions": {
                name: {"successes": rec["successes"], "n": rec["n"], "rate": rec["rate"]}
                for name, rec in summary["conditions"].items()
            },
            "paired_difference": summary["paired_difference"],
            "falsifier": summary["falsifier"],
            # a stopping rule's looks, the look it stopped at and the N it used
            **({"stopping": summary["stopping"]} if "stopping" in summary else {}),
        },
        "stamps": stamps,
    }
    # a task's `valid_state`: the drawn states it rejected (the states stamp's record)
    for stamp in stamps.values():
        if stamp.get("rule") == EVALUATION_RULE and REDRAWN in stamp["extra"]:
            manifest[REDRAWN] = stamp["extra"][REDRAWN]
    inputs = {rel(p): p for p in [*outputs, summary_path]}
    registered = read_registration(registration) if registration is not None else None
    if registered is not None:
        manifest["registration"] = {
            "path": rel(registration),
            **manifest_section(
                config,
                registered,
                stamps=stamps,
                seen=deviations_seen(Layout(registration.parent)),
                repo_root=repo_root,
            ),
        }
        inputs[rel(registration)] = registration
    return manifest, inputs


def task_record(config: Mapping[str, Any], *, repo_root: Path = REPO_ROOT) -> dict[str, Any]:
    """What the manifest says of the task: where it is, what it is, what its policy reads
    (each observation's real-world source, and the protocol parameters of its errors) and the
    privileged observations allowed, with why."""
    task = load_task(config["task"], repo_root=repo_root)
    controller = task.controller
    read = getattr(controller, "observations", ())
    sources = {o.name: o.source for o in task.observations}
    record = {
        "reference": config["task"],
        "name": task.name,
        "title": task.title,
        "controller": "closed loop" if read else "open loop",
        "observations": {name: sources[name] for name in read},
        "privileged_observations": dict(config.get("privileged_observations") or {}),
    }
    errors = {o.name: o.errors.parameters() for o in task.observations if o.errors}
    if any(name in errors for name in read):  # each error's protocol parameter, by role
        record["observation_errors"] = {name: errors[name] for name in read if name in errors}
    if task.source is not None and str(config["task"]).endswith(".py"):
        record["sha256"] = provenance.file_sha256(task.source)
    return record
