"""What the report says of the registered design: when it was registered (and whether that was
before every rollout, from the manifest's `registration`), every deviation from it with the
results it produced, and the registered power plan."""

from __future__ import annotations

import json
from collections.abc import Mapping
from typing import Any

from mjtrial.design.registration import first_rollout
from mjtrial.stats.power import plan_lines


def _date(utc: str) -> str:
    return utc.replace("T", " ").removesuffix("Z") + " UTC"


def falsifier_clause(manifest: Mapping[str, Any]) -> str:
    """How the falsifier's sentence begins: what is true of when the design was fixed."""
    record = manifest.get("registration")
    if not record:
        return "Not registered (a run before registrations existed): "
    when = _date(record["registered_utc"])
    if record["deviations"]:
        return (
            f"Registered on {when}, but this run's design deviates from the registration "
            "(see Registration): "
        )
    if _existed(record):
        return f"Registered on {when}, after results existed (see Registration): "
    if record["before_any_rollout"]:
        return f"Registered on {when}, before any rollout: "
    first = first_rollout(manifest.get("stamps") or {})
    return (
        f"Registered on {when}, after rollouts existed (the first on {_date(first)}): "
        if first
        else f"Registered on {when}: "
    )


def _existed(entry: Mapping[str, Any]) -> bool:
    return bool((entry.get("results_when_registered") or {}).get("existed"))


def _results_seen(entry: Mapping[str, Any]) -> str:
    """What results existed when a registration was made (its `results_when_registered`)."""
    seen = entry.get("results_when_registered") or {}
    where = [
        f"{seen.get('files', 0)} file(s) in the results folder",
        f"{seen.get('records', 0)} of Snakemake's records of outputs",
    ]
    hashes = ", ".join(
        f"`{rel}` sha256 `{sha[:12]}`" for rel, sha in (seen.get("sha256") or {}).items()
    )
    return f"{' and '.join(where)}" + (f" ({hashes})" if hashes else "")


def _value(value: Any) -> str:
    text = json.dumps(value, ensure_ascii=False, default=str)
    return f"`{text if len(text) <= 60 else text[:57] + '...'}`"


def registration_lines(manifest: Mapping[str, Any], summary: Mapping[str, Any]) -> list[str]:
    """The report's Registration section (nothing for a run without a registration)."""
    record = manifest.get("registration")
    if not record:
        return []
    lines = ["## Registration", ""]
    when = _date(record["registered_utc"])
    where = f"(`{record['path']}`, design sha256 `{record['design_sha256'][:12]}`)"
    first = first_rollout(manifest.get("stamps") or {})
    if record["deviations"]:  # true of the registration, not of this run's design
        lines.append(f"The design was registered on {when} {where}; this run changed it.")
    elif record["before_any_rollout"]:
        lines.append(f"The design was registered on {when}, before any rollout {where}.")
    elif first:
        lines.append(
            f"The design was registered on {when}, after the first rollout of these results "
            f"({_date(first)}) {where}."
        )
    else:
        lines.append(f"The design was registered on {when} {where}.")
    if record.get("reason"):
        lines[-1] += f" Reason given: {record['reason']}."
    if _existed(record):
        lines.append(
            f"**It was registered after results existed**: {_results_seen(record)} were there "
            "when it was made, so it does not fix the design before the data."
        )
    for earlier in record.get("earlier", []):
        lines.append(
            f"It replaced a registration of {_date(earlier['registered_utc'])} (design sha256 "
            f"`{str(earlier.get('design_sha256'))[:12]}`, superseded on "
            f"{_date(earlier['superseded_utc'])}; kept in the file)."
        )
        if _existed(earlier):
            lines[-1] += f" It was made after results existed: {_results_seen(earlier)}."
    lines.append("")
    deviations = record["deviations"]
    if not deviations:
        lines.append("This run's design is the registered one: no deviation.")
    else:
        noted = record.get("deviation_noted") or {}
        verdict = summary.get("falsifier", {}).get("verdict", "?")
        lines.append(
            f"**This run deviates from the registered design** ({len(deviations)} "
            f"change{'s' if len(deviations) != 1 else ''}); its results, the falsifier's "
            f"verdict **{verdict.upper()}** included, are those of the changed design:"
        )
        lines.append("")
        lines += ["| key | registered | this run |", "| --- | --- | --- |"]
        lines += [
            f"| `{c['key']}` | {_value(c['registered'])} | {_value(c['now'])} |" for c in deviations
        ]
        lines.append("")
        if noted.get("results_existed"):
            of = (
                "of the registered design"
                if noted.get("of_registered_design")
                else "of an earlier design"
            )
            lines.append(
                f"The change was first run on {_date(noted['first_run_utc'])}, when results "
                f"existed: a summary {of} (verdict {str(noted.get('verdict')).upper()}) was "
                "on disk. The design was changed after its results were seen."
            )
        elif noted:
            lines.append(
                f"The change was first run on {_date(noted['first_run_utc'])}, when no result "
                "existed."
            )
    plan = record.get("plan")
    if plan:
        lines += ["", "### Power before the run", ""]
        lines.append(
            "What the registered N can detect, computed at registration (`mjtrial plan`; the "
            "exact power of McNemar's test over the binomial number of discordant pairs):"
        )
        lines += ["", *plan_lines(plan)]
    return lines
