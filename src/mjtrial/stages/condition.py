"""What a condition runs: its task on its model, its protocol parameters and thresholds, and the
length of its episodes. Apart from the rollout stage (which records with Rerun) so that
Snakemake's process can size the rollout jobs when it builds the DAG without importing it."""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path
from typing import Any

import mujoco

from mjtrial import REPO_ROOT
from mjtrial.design.conditions import model_edits, policy_path
from mjtrial.sim import engine
from mjtrial.sim.physics import load_model
from mjtrial.studies.variants import variant_model
from mjtrial.task import BoundTask, load_task


def condition_task(
    condition_slice: Mapping[str, Any], model_file: Path, *, repo_root: Path = REPO_ROOT
) -> BoundTask:
    """The task a condition runs, on its model: the committed one, edited by the slice's
    variant, then by the condition's own model edits (`conditions.<name>.model`); with its
    policy file as the policy where it names one (`conditions.<name>.policy`)."""
    task = load_task(condition_slice["task"], repo_root=repo_root)
    policy = policy_path(condition_slice)
    if policy:
        from mjtrial.policy_files.file import load_policy_file, policy_task  # a policy's job only

        task = policy_task(task, load_policy_file(Path(repo_root) / policy, task))
    return BoundTask.of(task, condition_model(condition_slice, model_file))


def condition_model(condition_slice: Mapping[str, Any], model_file: Path) -> mujoco.MjModel:
    """The model a condition's episodes run on (see `condition_task`)."""
    variant = condition_slice.get("variant")
    edits = model_edits(condition_slice)
    if variant is None and not edits:
        return load_model(model_file)
    overrides, prefix = (
        ({}, "model") if variant is None else (variant["overrides"], f"variants.{variant['name']}")
    )
    condition = condition_slice.get("condition", "condition")
    then = [(edits, f"conditions.{condition}.model")] if edits else []
    return variant_model(model_file, overrides, key_prefix=prefix, then=then)[0]


def condition_parameters(bound: BoundTask, condition_slice: Mapping[str, Any]) -> dict[str, float]:
    """The condition's protocol parameters, from its slice."""
    names = {p.name for p in bound.task.protocol_parameters}
    return {k: v for k, v in condition_slice.items() if k in names}


def episode_steps_of(
    condition_slice: Mapping[str, Any], model_file: Path, *, repo_root: Path = REPO_ROOT
) -> int:
    """Physics steps of one of the condition's episodes, from its task's protocol on its model
    (the policy file, which runs on the task's timing, is not loaded): a rollout job's work is
    its states times this, and Snakemake starts the longest jobs first (rule rollout's
    priority)."""
    bound = BoundTask.of(
        load_task(condition_slice["task"], repo_root=repo_root),
        condition_model(condition_slice, model_file),
    )
    return engine.episode_steps(bound, condition_parameters(bound, condition_slice))


def thresholds_of(bound: BoundTask, condition_slice: Mapping[str, Any]) -> dict[str, float]:
    """The failure categories' thresholds: the config's `failure_taxonomy`, else defaults."""
    given = condition_slice.get("failure_taxonomy", {})
    return {t.name: float(given.get(t.name, t.default)) for t in bound.task.thresholds}

