"""The report's section on a stopping rule: each look's e-value, where the run stopped, and
what the stop does and does not license (`mjtrial.sequential`)."""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any


def stopping_section(summary: Mapping[str, Any]) -> list[str]:
    """The "Stopping early" section, or nothing for an experiment without a stopping rule."""
    rule = summary.get("stopping")
    if not rule:
        return []
    treatment = summary["paired_difference"]["treatment"]
    baseline = summary["paired_difference"]["baseline"]
    lines = [
        "## Stopping early",
        "",
        f"Chosen before the data: a {rule['method']}, alpha = {rule['alpha']:g}: the states run "
        f"in the order of the states table, {rule['block']} at a time (a shard), and after each "
        f"block the e-value of the discordant pairs so far is compared with 1/alpha = "
        f"{rule['threshold']:g}; the run stops when it reaches it, or at the maximum N = "
        f"{rule['max_n']}. Prior: {rule['prior']}.",
        "",
        f"| look | states | discordant pairs ({treatment} only / all) | e-value |",
        "| --- | --- | --- | --- |",
        *(
            f"| {look['look']} | {look['n']} | {look['treatment_only']}/{look['discordant']} | "
            f"{look['e_value']:.3g} |"
            for look in rule["looks"]
        ),
        "",
    ]
    if rule["rejected"]:
        lines.append(
            f"Stopped at look {rule['stopped_at_look']}, after {rule['n_used']} of "
            f"{rule['max_n']} states: the null of no paired difference is rejected in the "
            f"falsifier's direction ({treatment} better than {baseline}) with a type-I error of "
            f"at most {rule['alpha']:g} over every look (Ville's inequality). The rates, "
            "intervals and tests above are computed on these states as if their number had "
            "been fixed in advance: after an early stop they are not adjusted for it, and the "
            "estimate is biased away from zero; the stop is the decision whose error is bounded."
        )
    else:
        lines.append(
            f"The e-value never reached {rule['threshold']:g}: all {rule['n_used']} states ran, "
            "and the falsifier is judged by the analysis above as without a stopping rule."
        )
    return lines
