"""How the report names things, shared by the figures and the Markdown text: units, band
labels, confidence levels and the failure categories in their order."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

from mjtrial.analysis import condition_settings
from mjtrial.design.conditions import MODEL_EDITS, POLICY
from mjtrial.studies.variants import describe_edits
from mjtrial.task import Task


def band_parameter(parameter: str, task: Task) -> tuple[str, str]:
    """(readable name, unit) of a band parameter such as `mass` or `abs_dx`."""
    base = parameter.removeprefix("abs_")
    label = f"|{base}|" if parameter.startswith("abs_") else base
    return label, task.unit_of(base)


def setting(record: Mapping[str, Any], task: Task) -> str:
    """A condition's protocol parameters from its summary record, then its edits of the model
    and its policy file: `push_time 0.25 s`, `latency 0.02 s, joint hinge frictionloss 0.2`,
    `latency 0 s, policy policies/mlp/seed-0.onnx`."""
    edits, policy = record.get(MODEL_EDITS), record.get(POLICY)
    return ", ".join(
        [f"{k} {v:g} {task.unit_of(k)}".rstrip() for k, v in condition_settings(record).items()]
        + ([describe_edits(edits)] if edits else [])
        + ([f"policy {policy}"] if policy else [])
    )


def pct(confidence: float) -> str:
    """A confidence level as a percentage: 0.95 -> `95%`."""
    return f"{confidence * 100:g}%"


def failure_categories(summary: Mapping[str, Any], order: Sequence[str]) -> list[str]:
    """Every category of the task (`order`, first match first), plus any other named in the
    summary."""
    categories = list(order)
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


def _cell(value: Any) -> str:
    # A bare "|" (as in the band name "|dx|") would end the cell.
    return str(value).replace("|", "\\|")


def markdown_table(header: Sequence[Any], rows: Sequence[Sequence[Any]]) -> list[str]:
    """A Markdown table's lines: the header, the rule, a line per row."""
    lines = ["| " + " | ".join(_cell(h) for h in header) + " |", "|" + " --- |" * len(header)]
    lines += ["| " + " | ".join(_cell(c) for c in row) + " |" for row in rows]
    return lines
