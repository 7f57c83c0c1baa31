"""The conditions an experiment runs: the design's own, and those its dose-response sweep adds.

A sweep runs one protocol parameter over several values, each value a condition: the sweep's
base condition with that parameter set. A value whose condition equals one of the design's
conditions is that condition (a sweep of `push_time` whose value 0.25 s is the `firm`
condition's), so its episodes are never run twice; the others are named
`<parameter>-<value>` (`push_time-0.5`).
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

MODEL_EDITS = "model"  # a condition's edits of the model, beside its protocol parameters
POLICY = "policy"  # a condition's policy file (`mjtrial.policy_files.file`), replacing the task's


def model_edits(condition: Mapping[str, Any]) -> dict[str, Any]:
    """A condition's edits of the model (`mjtrial.studies.variants` overrides), or {}."""
    return dict(condition.get(MODEL_EDITS) or {})


def policy_path(condition: Mapping[str, Any]) -> str | None:
    """The policy file a condition runs instead of the task's policy (relative to the
    repository), or None."""
    return condition.get(POLICY)


def condition_record(task: Any, condition: Mapping[str, Any]) -> dict[str, Any]:
    """What a summary or a report records of a condition: its protocol parameters as numbers
    (`Task.condition_values`), and its edits of the model where it has any."""
    edits, policy = model_edits(condition), policy_path(condition)
    return {
        **task.condition_values(condition),
        **({MODEL_EDITS: edits} if edits else {}),
        **({POLICY: policy} if policy else {}),
    }


def sweep_base(config: Mapping[str, Any]) -> str:
    """The condition a sweep starts from: `sweep.base`, else the falsifier's baseline."""
    return config["sweep"].get("base", config["design"]["falsifier"]["baseline"])


def sweep_conditions(config: Mapping[str, Any]) -> dict[float, str]:
    """Each swept value, in increasing order, with the name of the condition that runs it."""
    if "sweep" not in config:
        return {}
    sweep = config["sweep"]
    base = dict(config["conditions"][sweep_base(config)])
    named: dict[float, str] = {}
    for value in sorted(float(v) for v in sweep["values"]):
        params = {**base, sweep["parameter"]: value}
        same = [n for n, c in config["conditions"].items() if _same(c, params)]
        named[value] = same[0] if same else f"{sweep['parameter']}-{value:g}"
    return named


def _same(a: Mapping[str, Any], b: Mapping[str, Any]) -> bool:
    return a.keys() == b.keys() and all(
        a[k] == b[k] if k in (MODEL_EDITS, POLICY) else float(a[k]) == float(b[k]) for k in a
    )


def all_conditions(config: Mapping[str, Any]) -> dict[str, dict[str, Any]]:
    """Every condition of the nominal model: the design's, then the sweep's new ones."""
    out = {name: dict(c) for name, c in config["conditions"].items()}
    if "sweep" in config:
        base = config["conditions"][sweep_base(config)]
        for value, name in sweep_conditions(config).items():
            out.setdefault(name, {**base, config["sweep"]["parameter"]: value})
    return out


def sensitivity_conditions(config: Mapping[str, Any]) -> list[str]:
    """The conditions the sensitivity study reads under every variant: the falsifier's two
    first, then the design's others, so that every condition's rates and flipped outcomes are
    counted (a condition that collapses under a variant is said, not left out)."""
    falsifier = config["design"]["falsifier"]
    pair = [falsifier["treatment"], falsifier["baseline"]]
    return pair + [c for c in config["conditions"] if c not in pair]


def variant_names(config: Mapping[str, Any]) -> list[str]:
    """The simulator variants of the sensitivity study, in config order."""
    return list(config.get("variants") or {})
