"""The report's section on a stopping rule: each look's e-value, where the run stopped, and
what the stop does and does not license (`mjtrial.stats.sequential`)."""

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
        f"Chosen before the data: a {rule['method']}, one-sided at alpha = {rule['alpha']:g}: "
        f"the states run in the order of the states table, {rule['look_every']} at a time, and "
        f"after each block the e-value of the discordant pairs so far is compared with the "
        f"threshold {rule['threshold']:.4g} ({rule['threshold_method']}: under the null of no "
        f"paired difference it is reached at some look with probability "
        f"{rule['error_bound']:.4f}, at most alpha); the run stops when it is reached, or at "
        f"the maximum N = {rule['max_n']}. The falsifier's verdict is this test's decision, "
        f"the last look at N included: one error budget. Prior: {rule['prior']}.",
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
            f"at most {rule['alpha']:g} over every look. The rates, intervals and tests above "
            "are computed on these states as if their number had been fixed in advance: they "
            "are not adjusted for the stop (the intervals are no confidence sequence, and may "
            "cover less than their level under this rule), and the estimate is biased away "
            "from zero; the stop is the decision whose error is bounded."
            if rule["n_used"] < rule["max_n"]
            else f"The threshold was reached at the last look, N = {rule['max_n']}: the null "
            f"of no paired difference is rejected in the falsifier's direction ({treatment} "
            f"better than {baseline}) with a type-I error of at most {rule['alpha']:g} over "
            "every look."
        )
    else:
        lines.append(
            f"The e-value never reached {rule['threshold']:.4g}: all {rule['n_used']} states "
            "ran, and the falsifier is refuted by this test (no difference in its direction "
            f"shown at one-sided {rule['alpha']:g}); the rates, interval and McNemar test above "
            "are those of a fixed N."
        )
    return lines
