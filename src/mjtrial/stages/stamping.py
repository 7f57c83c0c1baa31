"""What every stage shares: its config slice, its code record and its outputs' stamp."""

from __future__ import annotations

import json
from collections.abc import Mapping
from functools import cache
from pathlib import Path
from typing import Any

from mjtrial import REPO_ROOT, provenance
from mjtrial.crate.description import crate_description
from mjtrial.design.conditions import all_conditions, sensitivity_conditions
from mjtrial.files import codehash
from mjtrial.files.layout import CONDITION_STAGES, STAGES
from mjtrial.sim.simenv import VERSION_KEY, model_overrides, variant_version
from mjtrial.task import task_files


class ConfigSlice(dict):
    """A config slice whose text form is JSON with `<`, `>` and `&` escaped: Snakemake writes
    a rule's params with `repr` into its metadata (what decides reruns) and into the JSON of
    `snakemake --report`'s page, where design text with "</script>" would end the script."""

    def __repr__(self) -> str:
        text = json.dumps(self, ensure_ascii=False, default=str)
        return text.replace("&", "\\u0026").replace("<", "\\u003c").replace(">", "\\u003e")

    __str__ = __repr__


def config_slice(
    stage: str, config: Mapping[str, Any], *, condition: str | None = None
) -> ConfigSlice:
    """The part of the config a stage depends on: its rule's params and its stamp's record.

    Changing a value outside a stage's slice never reruns that stage. The failures stage
    and the seal depend on no config value.
    """
    return ConfigSlice(_slice(stage, config, condition=condition))


def _slice(
    stage: str, config: Mapping[str, Any], *, condition: str | None = None
) -> dict[str, Any]:
    if stage == "states":  # the task declares the parameters and their draw order
        return {**config["states"], "task": config["task"]}
    if stage in CONDITION_STAGES:  # condition: "<condition>" or "<variant>/<condition>"
        variant, _, name = condition.rpartition("/")
        condition_slice = {
            "condition": name,
            "task": config["task"],
            **all_conditions(config)[name],
            "failure_taxonomy": dict(config["failure_taxonomy"]),
            "recording": {k: config["recording"][k] for k in ("rate_hz", "episodes")},
        }
        if variant:
            edits = config["variants"][variant]
            condition_slice["variant"] = {"name": variant, "overrides": model_overrides(edits)}
            if variant_version(edits):  # another MuJoCo version (mjtrial.sim.simenv)
                condition_slice["variant"][VERSION_KEY] = variant_version(edits)
        return condition_slice
    if stage == "sensitivity":
        return {
            "conditions": {c: config["conditions"][c] for c in sensitivity_conditions(config)},
            "variants": dict(config["variants"]),
            "falsifier": dict(config["design"]["falsifier"]),
            "analysis": _analysis_settings(config),
        }
    if stage == "dose_response":
        return {
            "task": config["task"],
            "sweep": dict(config["sweep"]),
            "conditions": all_conditions(config),
            "bands": dict(list(config["analysis"]["bands"].items())[:1]),
            "analysis": _analysis_settings(config),
            **({"stopping": stopping_settings(config)} if "stopping" in config else {}),
        }
    if stage == "analysis":
        return {
            "task": config["task"],
            "conditions": dict(config["conditions"]),
            "falsifier": dict(config["design"]["falsifier"]),
            "sample_size": dict(config["design"]["sample_size"]),
            "analysis": dict(config["analysis"]),
            **({"stopping": stopping_settings(config)} if "stopping" in config else {}),
        }
    if stage == "look":  # a stopping rule's look after a shard (mjtrial.stages.look)
        return {
            "falsifier": {k: config["design"]["falsifier"][k] for k in ("treatment", "baseline")},
            "stopping": stopping_settings(config),
        }
    if stage == "pilot_summary":  # the design's conditions' rates on the development states
        return {
            "task": config["task"],
            "conditions": dict(config["conditions"]),
            "confidence": config["analysis"]["confidence"],
        }
    if stage == "figures":  # the words and traces of the task and each condition
        return {"task": config["task"], "conditions": dict(config["conditions"])}
    if stage == "failures":
        return {"failures_max": config["recording"]["failures_max"]}
    if stage == "seal":
        return {}
    if stage == "crate":  # the crate's license, authors and keywords
        return crate_description(config)
    if stage in ("manifest", "report"):
        # The whole design, but not the studies' (their own outputs record it): adding a
        # variant never reruns the built-in experiment, only the report when it is the first
        # (its scope says whether a study is declared); nor the crate's authors and keywords
        # (the crate records them): naming an author reruns the crate alone.
        design = {k: v for k, v in config.items() if k not in ("variants", "sweep")}
        if "provenance" in design:
            design["provenance"] = {
                k: v for k, v in design["provenance"].items() if k not in ("authors", "keywords")
            }
        if stage == "report":  # it says which studies the config declares, not what they hold
            design[DECLARED_STUDIES] = declared_studies(config)
        return design
    raise ValueError(f"stage: expected one of {list(STAGES)}, got {stage!r}")


# The report's slice keeps which studies the config declares (`declared_studies`), without
# their variants or sweep: its scope says whether a sensitivity study exists.
DECLARED_STUDIES = "declared_studies"


def declared_studies(config: Mapping[str, Any]) -> list[str]:
    """The studies the config declares: `sensitivity` (variants), `dose_response` (a sweep)."""
    keys = {"sensitivity": "variants", "dose_response": "sweep"}
    return [study for study, key in keys.items() if config.get(key)]


def stopping_settings(config: Mapping[str, Any]) -> dict[str, Any]:
    """The stopping rule as it runs: the config's `stopping` (a look after every `look_every`
    states) and its maximum N (`states.n`)."""
    return {**config["stopping"], "max_n": config["states"]["n"]}


def _analysis_settings(config: Mapping[str, Any]) -> dict[str, Any]:
    """What the studies' statistics use of `analysis`: the main result's settings."""
    return {k: config["analysis"][k] for k in ("confidence", "n_resamples", "seed")}


@cache
def stage_code(stage: str) -> dict[str, str]:
    """sha256 of the stage's workflow script and of every package module it runs, by name."""
    return codehash.script_code(STAGES[stage].script_path, repo_root=REPO_ROOT)


def stage_code_hash(stage: str) -> str:
    """One digest of `stage_code(stage)`: a rule's `code` param."""
    return codehash.code_digest(stage_code(stage))


def model_inputs(model_file: Path) -> dict[str, Any]:
    """A stamp's record of the model: the scene, and the other files it is built from."""
    scene, *included = provenance.model_files(model_file)
    return {"model": scene, "model_files": included}


def task_inputs(reference: str, *, repo_root: Path = REPO_ROOT) -> dict[str, Any]:
    """A stamp's record of the task: every file of its folder (`task.task_files`), when the
    config names it by path (a task named by module is code of an installed package, recorded
    by the library versions)."""
    if not str(reference).endswith(".py"):
        return {}
    files = task_files(Path(repo_root) / reference)
    return {"task": files[0] if len(files) == 1 else files}


def make_stage_stamp(
    rule: str,
    config_slice: Any,
    inputs: Mapping[str, Any],
    *,
    seeds: Mapping[str, int] | None = None,
    threads: int | None = None,
    repo_root: Path = REPO_ROOT,
    extra: Mapping[str, Any] | None = None,
) -> dict[str, Any]:
    """The stamp of a stage's outputs; `rule` is `<stage>` or `<stage>:<qualifier>`. `threads`:
    the simulation threads the job ran (a rollout's), recorded beside the machine's CPU;
    `extra`: what else the stage records (how a policy file ran)."""
    stage = rule.split(":")[0]
    threads_record = {} if threads is None else {"threads": int(threads)}
    return provenance.make_stamp(
        rule=rule,
        config_slice=config_slice,
        inputs=inputs,
        seeds=seeds,
        repo_dir=repo_root,
        extra={
            "code_sha256": stage_code_hash(stage),
            "code": stage_code(stage),
            **(extra or {}),
            **threads_record,
        },
    )
