"""How the report names things, shared by the figures and the Markdown text: units, band
labels, confidence levels and the failure categories in their order."""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

from mjtrial.taxonomy import FailureCategory

# Units of the state parameters a band table can sort by (mjtrial.states.STATE_PARAMETERS).
UNITS = {"dx": "m", "dy": "m", "yaw": "rad", "mass": "kg"}


def band_parameter(parameter: str) -> tuple[str, str]:
    """(readable name, unit) of a band parameter such as `mass` or `abs_dx`."""
    base = parameter.removeprefix("abs_")
    label = f"|{base}|" if parameter.startswith("abs_") else base
    return label, UNITS.get(base, "")


def pct(confidence: float) -> str:
    """A confidence level as a percentage: 0.95 -> `95%`."""
    return f"{confidence * 100:g}%"


def failure_categories(summary: Mapping[str, Any]) -> list[str]:
    """Every category of the taxonomy, in its order, plus any other named in the summary."""
    categories = [c.value for c in FailureCategory]
    for counts in summary["failures"].values():
        categories += [c for c in counts if c not in categories]
    return categories


def rate_cell(rec: Mapping[str, Any]) -> str:
    """`k/n rate [low, high]`, the one format of a success rate in the reports."""
    if not rec["n"]:
        return "no states"
    return (
        f"{rec['successes']}/{rec['n']} {rec['rate']:.3f} "
        f"[{rec['wilson_low']:.3f}, {rec['wilson_high']:.3f}]"
    )
