"""The config check of the studies (variants, sweeps) and of a condition's model edits: what
`mjtrial.config.check_config` refuses when an edit changes nothing, a variant a condition
undoes, or a variant that does not apply; split from `mjtrial.config` by size."""

from __future__ import annotations

from collections.abc import Callable, Mapping
from pathlib import Path
from typing import Any

import mujoco
import numpy as np

from mjtrial.design.conditions import model_edits
from mjtrial.sim.contacts import describe_contact_changes
from mjtrial.sim.engine import iter_batches
from mjtrial.sim.simenv import model_overrides, variant_version
from mjtrial.studies.variants import resolved_values, variant_model
from mjtrial.task import BoundTask, Task, TaskError
from mjtrial.task.checks import (
    episodes_sha256,
    nominal_episode_sha256,
)

# What "changes nothing" means for an edit of the model, said once for conditions and variants.
_SAME_SIMULATION = (
    "the edited model simulates as the committed one (`physics.simulated_sha256`: a colour, a "
    "name, a value every element overrides or MuJoCo ignores); expected an edit of the physics"
)


def _changes_nothing(committed: mujoco.MjModel, edited: mujoco.MjModel) -> str:
    """Why an edit simulates as the committed model: in its contacts' terms where it edited a
    geom's contact parameters ("`block` friction 0.8 -> 0.4; its contacts with `jaw` keep their
    values"), since MuJoCo mixes each pair's from its two geoms and a geom's own never acts."""
    said = describe_contact_changes(committed, edited) if committed.ngeom == edited.ngeom else []
    if not said:
        return f"changes nothing: {_SAME_SIMULATION}"
    return (
        f"changes nothing: {'; '.join(said)} (MuJoCo mixes each pair's contact parameters from "
        "its two geoms: the larger friction and condim, or the higher priority's); expected an "
        "edit of the physics"
    )


def _check_variant_applies(
    config: Mapping[str, Any],
    name: str,
    model_file: Path,
    task: Task,
    fail: Callable[[str, str], None],
) -> None:
    """A variant's run of a condition applies the condition's own edits of the model after the
    variant's (`variant_model`'s `then`), so a value both set is the condition's: that run
    would be the nominal one, yet counted and given a verdict as the variant's. Refused, naming
    the value; and where the edits undo the variant otherwise (a class's value every element
    of the condition sets), the runs' simulations are compared."""
    variant = config["variants"][name]
    overrides = model_overrides(variant)
    # by the element each value reaches, whatever name or address each gave it (`floor`, `#0`)
    changed = resolved_values(model_file, overrides)
    for condition, spec in config["conditions"].items():
        edits = model_edits(spec)
        if not edits:
            continue
        where = f"conditions.{condition}.model"
        for reached, value in resolved_values(model_file, edits).items():
            if reached in changed:
                fail(
                    f"variants.{name}.{changed[reached]}",
                    f"condition {condition!r} sets it too ({where}.{value}), and a condition's "
                    f"edits apply after a variant's: the variant's run of {condition!r} would "
                    "keep the condition's value, yet be counted as the variant's; expected a "
                    "variant and conditions that edit different values",
                )
        if variant_version(variant) is not None:
            continue  # its own MuJoCo runs it: never the nominal run
        try:
            runs = [
                BoundTask.of(task, variant_model(model_file, o, key_prefix=where, then=then)[0])
                for o in (overrides, {})
                for then in [[(edits, where)]]
            ]
        except (ValueError, TaskError) as err:  # ModelError included: one line
            fail(f"variants.{name}", f"with condition {condition!r}'s edits: {err}")
        if nominal_episode_sha256(runs[0]) == nominal_episode_sha256(runs[1]):
            fail(
                f"variants.{name}",
                f"changes nothing in condition {condition!r}: its edits ({where}) undo the "
                "variant's, so the variant's run of it would be the nominal one; expected a "
                "variant and conditions that edit different values",
            )


def _unstable(
    bound: BoundTask,
    conditions: Mapping[str, Mapping[str, Any]],
    thresholds: Mapping[str, float],
    *,
    runs: dict[str, tuple[BoundTask, str]] | None = None,
) -> str | None:
    """Why the model cannot run the task, or None: it runs the nominal episode (each state
    parameter at its nominal value) under every condition. `runs` gets each condition's bound
    task and its nominal episode's hash (`task_checks.alike_conditions`)."""
    task = bound.task
    nominal = {p.name: np.array([p.nominal_value]) for p in task.state_parameters}
    given = {t.name: float(thresholds.get(t.name, t.default)) for t in task.thresholds}
    for name, condition in conditions.items():
        # MuJoCo prints each warning; the one line below says it instead.
        printer = mujoco.get_mju_user_warning()
        mujoco.set_mju_user_warning(lambda _: None)
        try:
            batch = next(iter_batches(bound, nominal, condition, thresholds=given, nthread=0))
        finally:
            mujoco.set_mju_user_warning(printer)
        if runs is not None:
            runs[name] = (bound, episodes_sha256(batch.episodes))
        outcome = batch.outcome
        if outcome["nonfinite"][0] or outcome["warning"][0]:
            what = outcome["warning"][0] or "a non-finite state"
            return (
                f"unstable: the nominal episode under condition {name!r} stops at step "
                f"{outcome['steps_simulated'][0]} with {what}; expected a model that runs it "
                "without a MuJoCo warning"
            )
    return None
