"""The report's words for the planned comparisons: each paired difference with the interval
that is valid for it, the paired table, the tests and the family's correction.

Every number comes from the summary's `comparisons` (`mjtrial.analysis.compare`).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

from mjtrial.report.labels import markdown_table, pct


def signed_interval(low: float, high: float) -> str:
    return f"[{low:+.3f}, {high:+.3f}]"


def _bootstrap_how(record: Mapping[str, Any]) -> str:
    return f"({record['method']}, {record['n_resamples']} resamples, seed {record['seed']})"


def _role(record: Mapping[str, Any]) -> str:
    role = "primary (the falsifier's)" if record["primary"] else "secondary"
    return role + (", **exploratory**" if record["exploratory"] else "")


def paired_text(record: Mapping[str, Any]) -> str:
    """A comparison's paired difference with its interval (Newcombe's); where the bootstrap
    interval it replaces was degenerate (every pair's difference the same), why; at a ceiling
    or floor, that the comparison is at it."""
    paired = record["paired_difference"]
    conf = pct(paired["confidence"])
    head = (
        f"Paired difference {paired['treatment']} - {paired['baseline']}: "
        f"**{paired['estimate']:+.3f}**"
    )
    interval = signed_interval(paired["low"], paired["high"])
    replaced = paired.get("replaces")
    if replaced is None or replaced["low"] != replaced["high"]:
        return f"{head}, {conf} interval {interval} ({paired['method']})."
    degenerate = signed_interval(replaced["low"], replaced["high"])
    newcombe = (
        f"the {conf} interval given is by {paired['method']}, valid there: **{interval}**, the "
        "differences these states cannot rule out"
    )
    bound = record.get("bound")
    if bound is not None:
        every = "succeed" if bound == "ceiling" else "fail"
        return (
            f"{head}. The comparison is at its {bound}: both conditions {every} in every state "
            "(no discordant pair), so these states cannot show a difference either way; the "
            f"bootstrap interval {_bootstrap_how(replaced)} is degenerate there ({degenerate}: "
            f"resampling identical pairs cannot vary the mean) and is no measure of uncertainty; "
            f"{newcombe}."
        )
    return (
        f"{head}. Every state's difference is the same, so the bootstrap interval "
        f"{_bootstrap_how(replaced)} is degenerate ({degenerate}) and is no measure of "
        f"uncertainty; {newcombe}."
    )


def tests_text(record: Mapping[str, Any], family: Mapping[str, Any]) -> str:
    """The discordant pairs of a comparison and its McNemar p, raw and Holm-adjusted."""
    t, b = record["treatment"], record["baseline"]
    d, m = record["table"], record["mcnemar"]
    if record["exploratory"]:
        adjusted = "exploratory, not in the registered family: over every comparison tested"
    elif family["family"] == 1:
        adjusted = "the only planned comparison: no adjustment"
    else:
        adjusted = f"over the family of {family['family']} planned"
    return (
        f"Discordant pairs: {d[f'only_{t}']} states succeed only under {t}, {d[f'only_{b}']} "
        f"only under {b}; {m['method']} p = {m['p_value']:.3g}; {family['method']} adjusted "
        f"p = {m['p_holm']:.3g} ({adjusted})."
    )


def metric_lines(summary: Mapping[str, Any]) -> list[str]:
    """The Metric section's lines on the paired comparisons: the difference, its interval
    (and the one used where that is degenerate), the test and the family's correction."""
    records = summary["comparisons"]
    primary = records[0]["paired_difference"]
    bootstrap = primary.get("replaces", primary)
    names = ", ".join(f"{r['treatment']} - {r['baseline']}" for r in records)
    exploratory = [r for r in records if r["exploratory"]]
    family = summary["multiple_comparisons"]
    return [
        f"- Paired difference: the mean over states of success(treatment) - success(baseline), "
        f"with a {pct(primary['confidence'])} interval by {primary['method']}, whose coverage "
        "stays near its level at every number of states and rate; the percentile bootstrap "
        f"over pairs ({bootstrap['n_resamples']} resamples, seed {bootstrap['seed']}), which "
        "covers less with few states near 0 or 1 and none where every pair's difference is "
        "the same, is kept in the summary (`replaces`) only for comparison.",
        f"- Discordant pairs: {summary['mcnemar']['method']}.",
        f"- Comparisons planned in the config ({len(records)}): {names}; the first is the "
        "falsifier's (primary). "
        + (
            "A family of one: its p-value is not adjusted"
            if family["family"] == 1
            else f"p-values adjusted by {family['method']} over the {family['family']} planned"
        )
        + (
            f"; {len(exploratory)} exploratory (not in the registration), adjusted over every "
            "comparison tested"
            if exploratory
            else ""
        )
        + ".",
    ]


def comparisons_section(summary: Mapping[str, Any]) -> list[str]:
    """Every planned comparison after the primary one: a table of all of them, then each
    secondary one's difference and tests in words. Empty for the falsifier's comparison alone
    (the results say it already)."""
    records: Sequence[Mapping[str, Any]] = summary["comparisons"]
    if len(records) < 2:
        return []
    family = summary["multiple_comparisons"]
    conf = pct(summary["confidence"])
    rows = []
    for r in records:
        p = r["paired_difference"]
        t, b = r["treatment"], r["baseline"]
        rows.append(
            [
                f"{t} - {b}",
                _role(r),
                f"{p['estimate']:+.3f}",
                signed_interval(p["low"], p["high"])
                + (" (Newcombe)" if "replaces" in p else "")
                + (f", at its {r['bound']}" if r.get("bound") else ""),
                f"{r['table'][f'only_{t}']} / {r['table'][f'only_{b}']}",
                f"{r['mcnemar']['p_value']:.3g}",
                f"{r['mcnemar']['p_holm']:.3g}",
            ]
        )
    lines = [
        "### Planned comparisons",
        "",
        f"Each comparison runs on the same states; its interval is its own ({conf}, unadjusted); "
        f"the McNemar p-values are adjusted by {family['method']}, over the "
        f"{family['family']} planned comparisons"
        + (
            "; an exploratory comparison (added after the registration) over every comparison "
            "tested, and it is a lead for a new experiment, not a finding of this one"
            if any(r["exploratory"] for r in records)
            else ""
        )
        + ".",
        "",
    ]
    header = [
        "comparison",
        "role",
        "difference",
        f"{conf} interval",
        "discordant (only treatment / only baseline)",
        "McNemar p",
        "Holm p",
    ]
    lines += [*markdown_table(header, rows), ""]
    for r in records[1:]:
        lines += [paired_text(r), "", tests_text(r, family), ""]
    return lines
