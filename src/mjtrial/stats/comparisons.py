"""The planned comparisons: which pairs of conditions the analysis tests, named in the config
before the data (`analysis.comparisons`), and which of them a registration did not plan.

The falsifier's pair is always the first, primary, comparison; the others follow in the order
the config gives them. Pure functions over config sections: the config check, the analysis and
verify's recomputation all read the plan from here.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

AGAINST = "against"
"""The `analysis.comparisons` form that pairs every other condition with one baseline."""


@dataclass(frozen=True)
class Comparison:
    """One planned comparison: `treatment` minus `baseline`, on the same states.

    Attributes:
        treatment: the condition whose success is counted positive in the difference.
        baseline: the condition it is compared with.
        primary: whether it is the falsifier's comparison (the first of the family).
    """

    treatment: str
    baseline: str
    primary: bool = False

    @property
    def pair(self) -> tuple[str, str]:
        return (self.treatment, self.baseline)


def _listed_pairs(
    planned: Any, falsifier_pair: tuple[str, str], conditions: Sequence[str]
) -> list[tuple[str, str]]:
    """The config's pairs in its order: every other condition against the baseline for
    `{against: <baseline>}`, else the listed `[treatment, baseline]` pairs."""
    if planned is None:
        return []
    if isinstance(planned, Mapping):
        base = planned[AGAINST]
        # the falsifier's pair counts once, in its own orientation
        return [(c, base) for c in conditions if c != base and (base, c) != falsifier_pair]
    return [(str(t), str(b)) for t, b in planned]


def planned_comparisons(
    analysis: Mapping[str, Any], falsifier: Mapping[str, Any], conditions: Sequence[str]
) -> list[Comparison]:
    """The comparisons the analysis tests, the falsifier's first (primary), then the config's
    (`analysis.comparisons`; none: the falsifier's alone), each once.

    Args:
      analysis: the config's `analysis` section.
      falsifier: the design's falsifier (`treatment`, `baseline`).
      conditions: the condition names in config order (what `against` pairs with its baseline).
    """
    primary = (falsifier["treatment"], falsifier["baseline"])
    plan = [Comparison(*primary, primary=True)]
    for pair in _listed_pairs(analysis.get("comparisons"), primary, conditions):
        if pair != primary:
            plan.append(Comparison(*pair))
    return plan


def comparisons_error(
    analysis: Mapping[str, Any], falsifier: Mapping[str, Any], conditions: Sequence[str]
) -> tuple[str, str] | None:
    """`(key, expectation)` for the first wrong planned comparison, else None: a name that is
    no condition, a condition against itself, a pair listed twice (either way round)."""
    planned = analysis.get("comparisons")
    if planned is None:
        return None
    key = "analysis.comparisons"
    if isinstance(planned, Mapping):
        if planned[AGAINST] not in conditions:
            return (
                f"{key}.{AGAINST}",
                f"expected one of the conditions {sorted(conditions)}, got {planned[AGAINST]!r}",
            )
        return None
    primary = (falsifier["treatment"], falsifier["baseline"])
    seen: set[frozenset[str]] = set()
    for i, (treatment, baseline) in enumerate(planned):
        for name in (treatment, baseline):
            if name not in conditions:
                return (
                    f"{key}[{i}]",
                    f"expected conditions {sorted(conditions)}, got {name!r}",
                )
        if treatment == baseline:
            return f"{key}[{i}]", f"expected two different conditions, got {[treatment] * 2}"
        if (baseline, treatment) == primary:
            return (
                f"{key}[{i}]",
                f"the falsifier's comparison reversed; expected {list(primary)} (it is always "
                "tested, listed or not)",
            )
        pair = frozenset((treatment, baseline))
        if pair in seen:
            return f"{key}[{i}]", f"{[treatment, baseline]} is listed twice"
        seen.add(pair)
    return None


def registered_plan(registered: Mapping[str, Any] | None) -> set[frozenset[str]] | None:
    """The pairs of conditions a registration planned, read defensively from the config
    sections it registered (`registration.json`'s current design: its `analysis`,
    `design.falsifier` and `conditions`); None when nothing is registered."""
    if registered is None:
        return None
    config = registered
    analysis = config.get("analysis") or {}
    falsifier = (config.get("design") or {}).get("falsifier") or {}
    conditions = list(config.get("conditions") or {})
    pairs: set[frozenset[str]] = set()
    if "treatment" in falsifier and "baseline" in falsifier:
        primary = (falsifier["treatment"], falsifier["baseline"])
        pairs.add(frozenset(primary))
    else:
        primary = ("", "")
    pairs |= {frozenset(p) for p in _listed_pairs(analysis.get("comparisons"), primary, conditions)}
    return pairs


def exploratory(
    comparisons: Sequence[Comparison], registered: Mapping[str, Any] | None
) -> list[bool]:
    """Whether each comparison is exploratory: a registration exists (its record of the
    config, `registered`) and did not plan it. Nothing is exploratory without a registration."""
    plan = registered_plan(registered)
    if plan is None:
        return [False] * len(comparisons)
    return [frozenset(c.pair) not in plan for c in comparisons]
