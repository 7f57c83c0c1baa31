"""The studies' figures and report sections, drawn from `sensitivity.json` and
`dose_response.json` only: every number shown is formatted from them."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np
from matplotlib.figure import Figure

from mjtrial.recording.divergence import describe_divergence
from mjtrial.report.figures import (
    _GREY,
    _SHADE,
    CONDITION_PALETTE,
    DOUBLE_COLUMN,
    SINGLE_COLUMN,
    _figure,
    _save,
    _styled,
)
from mjtrial.report.labels import pct, rate_cell

STUDY_FIGURES = ("sensitivity_forest", "dose_response")
_VERDICT_STYLE = {  # colour, marker: survives blue, refuted vermillion, invalid hollow grey
    "survives": (CONDITION_PALETTE[1], "o"),
    "refuted": (CONDITION_PALETTE[0], "s"),
    "invalid": (_GREY, "X"),
}


@_styled
def figure_sensitivity_forest(*, sensitivity: Mapping[str, Any]) -> Figure:
    """The falsifier's statistic per variant with its interval and the threshold drawn."""
    variants = sensitivity["variants"]
    names = list(variants)
    falsifier = sensitivity["falsifier"]
    fig = _figure(SINGLE_COLUMN, 0.9 + 0.28 * len(names))
    ax = fig.add_subplot()
    y = np.arange(len(names))
    for i, name in enumerate(names):
        rec = variants[name]
        color, marker = _VERDICT_STYLE[rec["verdict"]]
        p = rec["paired_difference"]
        ax.errorbar(
            p["estimate"],
            i,
            xerr=[[p["estimate"] - p["low"]], [p["high"] - p["estimate"]]],
            fmt=marker,
            color=color,
            markerfacecolor="white" if rec["verdict"] == "invalid" else color,
            markersize=5,
            capsize=3,
            elinewidth=1.0,
            zorder=3,
        )
    ax.axvline(float(falsifier["threshold"]), color="black", linestyle=(0, (4, 3)), linewidth=0.9)
    labels = [
        f"{name}\n(invalid: {variants[name]['unhealthy']} unhealthy)"
        if variants[name]["verdict"] == "invalid"
        else name
        for name in names
    ]
    ax.set_yticks(y, labels)
    ax.invert_yaxis()
    ax.grid(axis="x", color=_SHADE, linewidth=0.6, zorder=0)
    ax.set_xlabel(
        f"{falsifier['treatment']} \u2212 {falsifier['baseline']} success\n"
        f"({pct(sensitivity['confidence'])} Newcombe interval)"
    )
    handles = [
        ax.plot([], [], _VERDICT_STYLE[v][1], color=_VERDICT_STYLE[v][0], label=v)[0]
        for v in _VERDICT_STYLE
        if any(rec["verdict"] == v for rec in variants.values())
    ]
    fig.legend(handles=handles, loc="outside lower center", ncols=len(handles))
    fig.suptitle(
        f"Falsifier under each simulator variant (threshold {float(falsifier['threshold']):g})",
        fontsize=9,
    )
    return fig


@_styled
def figure_dose_response(*, dose_response: Mapping[str, Any]) -> Figure:
    """Success against the swept value with Wilson bands, pooled and per band of the first
    band parameter."""
    rows = dose_response["per_value"]
    parameter = dose_response["parameter"]
    x = np.array([row[parameter] for row in rows])
    fig = _figure(DOUBLE_COLUMN, 2.8)
    pooled_ax, band_ax = fig.subplots(1, 2, sharey=True)

    def curve(ax: Any, recs: list[Mapping[str, Any]], color: str, marker: str, label: str) -> None:
        keep = [i for i, rec in enumerate(recs) if rec["n"]]
        rate = [recs[i]["rate"] for i in keep]
        ax.fill_between(
            x[keep],
            [recs[i]["wilson_low"] for i in keep],
            [recs[i]["wilson_high"] for i in keep],
            color=color,
            alpha=0.18,
            linewidth=0,
        )
        ax.plot(x[keep], rate, marker=marker, color=color, markersize=4, label=label)

    curve(pooled_ax, rows, "black", "o", f"pooled (n = {dose_response['n_states']})")
    band_unit = f" {dose_response['band_unit']}".rstrip()
    n_bands = len(rows[0]["bands"])
    for j in range(n_bands):
        recs = [row["bands"][j] for row in rows]
        band = recs[0]
        curve(
            band_ax,
            recs,
            CONDITION_PALETTE[j % len(CONDITION_PALETTE)],
            "osD^v"[j % 5],
            f"{band['low']:g}\u2013{band['high']:g}{band_unit} (n = {band['n']})",
        )
    furthest = dose_response["furthest_within_margin"]
    log = dose_response["scale"] == "log"
    unit = dose_response["unit"]
    axis = ", ".join(filter(None, [unit, "log scale" if log else ""]))
    for ax in (pooled_ax, band_ax):
        if log:
            ax.set_xscale("log")
        ax.set_xticks(x, [f"{v:g}" for v in x])
        ax.minorticks_off()
        ax.set_xlabel(f"{parameter.replace('_', ' ')} ({axis})" if axis else parameter)
        ax.grid(axis="y", color=_SHADE, linewidth=0.6, zorder=0)
        ax.axvline(furthest, color=_GREY, linestyle=":", linewidth=0.9)
        ax.legend(loc="lower right")
    # On the side of the line with room: the text never runs over the axis and its labels.
    room_right = list(x).index(furthest) < len(x) / 2
    pooled_ax.text(
        furthest,
        0.98,
        f" {'down' if dose_response['toward'] == 'smaller' else 'up'} to here: within "
        f"{dose_response['margin']:g} \n of {dose_response['reference']:g} {unit} ",
        transform=pooled_ax.get_xaxis_transform(),
        color=_GREY,
        va="top",
        ha="left" if room_right else "right",
    )
    pooled_ax.set_ylim(0, 1.04)
    pooled_ax.set_ylabel(f"Success rate ({pct(dose_response['confidence'])} Wilson band)")
    pooled_ax.set_title("Pooled")
    band_ax.set_title(f"Per {dose_response['band_parameter'].replace('_', ' ')} band")
    fig.suptitle(f"Success against {parameter.replace('_', ' ')}", fontsize=9)
    return fig


def _within_margin_sentence(d: Mapping[str, Any]) -> str:
    """The sweep's answer in the direction its values cost: "up to 0.02 s of latency, success
    stays within 0.05 of latency 0's"."""
    parameter, unit = d["parameter"], f" {d['unit']}".rstrip()
    furthest, reference = d["furthest_within_margin"], d["reference"]
    way = "Down" if d["toward"] == "smaller" else "Up"
    if furthest == reference:
        answer = (
            f"No {parameter} {d['toward']} than {reference:g}{unit} is shown to stay within "
            f"{d['margin']:g} of {reference:g}{unit}'s success"
        )
    else:
        answer = (
            f"{way} to {parameter} {furthest:g}{unit}, success is shown to stay within "
            f"{d['margin']:g} of {parameter} {reference:g}{unit}'s at every swept value"
        )
    alone = ", ".join(f"{v:g}" for v in d["values_within_margin"])
    criterion = d["within_margin_criterion"]
    return f"{answer} ({criterion}). Values within the margin on their own: {alone}."


def write_study_figures(
    *,
    sensitivity: Mapping[str, Any] | None,
    dose_response: Mapping[str, Any] | None,
    out_dir: Path,
    stamp: Mapping[str, Any],
) -> list[Path]:
    """Write the studies' figures present (`STUDY_FIGURES`) as stamped PNG and SVG."""
    paths: list[Path] = []
    if sensitivity is not None:
        fig = figure_sensitivity_forest(sensitivity=sensitivity)
        paths += _save(fig, out_dir=Path(out_dir), name=STUDY_FIGURES[0], stamp=stamp)
    if dose_response is not None:
        fig = figure_dose_response(dose_response=dose_response)
        paths += _save(fig, out_dir=Path(out_dir), name=STUDY_FIGURES[1], stamp=stamp)
    return paths


def _overrides(overrides: Mapping[str, Any]) -> str:
    """`option.timestep=0.001; geom.left_pad.friction=[0.6, 0.003, 0.0001]`, or `none`."""
    parts = []
    for kind, entries in overrides.items():
        if kind == "mujoco":  # another MuJoCo version (mjtrial.sim.simenv)
            parts.append(f"MuJoCo {entries}, in an environment of its own")
            continue
        for name, value in entries.items():
            if kind == "option":
                parts.append(f"{kind}.{name}={value}")
            else:
                parts += [f"{kind}.{name}.{a}={v}" for a, v in value.items()]
    return "; ".join(parts) or "none (as committed)"


def _judged_by(falsifier: Mapping[str, Any], conf: str) -> str:
    """How a variant's verdict is decided (`mjtrial.analysis.judge_falsifier`), in words."""
    if float(falsifier["threshold"]) == 0:
        return "refuted unless the exact McNemar test rejects no paired difference in its direction"
    return (
        f"refuted when the {conf} interval's lower bound is at or below {falsifier['threshold']:g}"
    )


def render_sensitivity_section(
    sensitivity: Mapping[str, Any],
    *,
    figure: str,
    contact_changes: Mapping[str, Sequence[str]] | None = None,
) -> str:
    """The report's "Sensitivity" section; `figure` is the forest plot's path for the link;
    `contact_changes`, per variant, what its edits of geoms do to their contacts
    (`mjtrial.sim.contacts.describe_contact_changes`)."""
    f = sensitivity["falsifier"]
    conf = pct(sensitivity["confidence"])
    names = list(next(iter(sensitivity["variants"].values()))["conditions"])
    head = "| variant | " + " | ".join(names) + " | difference [CI] | verdict | model sha256 |"
    lines = [
        "## Sensitivity",
        "",
        f"The falsifier ({f['statistic']}, {f['treatment']} \u2212 {f['baseline']}, judged as "
        f"in the main result: {_judged_by(f, conf)}) judged again on the same states under each "
        f"simulator variant. Success with {conf} Wilson intervals; the difference with a "
        f"{sensitivity['paired_difference_method']} interval. A variant is invalid when any "
        f"episode is unhealthy ({sensitivity['unhealthy_definition']}).",
        "",
        head,
        "| " + " | ".join(["---"] * (len(names) + 4)) + " |",
    ]
    for name, rec in sensitivity["variants"].items():
        p = rec["paired_difference"]
        verdict = rec["verdict"] + (f" ({rec['unhealthy']} unhealthy)" if rec["unhealthy"] else "")
        cells = [rate_cell(rec["conditions"][c]) for c in names]
        lines.append(
            f"| {name} | " + " | ".join(cells) + f" | {p['estimate']:+.3f} "
            f"[{p['low']:+.3f}, {p['high']:+.3f}] | {verdict} | `{rec['model_sha256'][:12]}` |"
        )
    lines += ["", "Overrides of each variant:", ""]
    for name, rec in sensitivity["variants"].items():
        lines.append(f"- {name}: {_overrides(rec['overrides'])}")
        lines += [f"  - in its contacts: {line}" for line in (contact_changes or {}).get(name, [])]
    for name, rec in sensitivity["variants"].items():
        if "flipped" in rec:
            lines += flipped_table(name, rec["flipped"])
    v = sensitivity["verdicts"]
    lines += [
        "",
        f"The conclusion survives {sensitivity['survives_in']} of {sensitivity['n_variants']} "
        f"variants (refuted in {v['refuted']}, invalid in {v['invalid']}).",
        "",
        f"![The falsifier's statistic per variant]({figure})",
        "",
    ]
    return "\n".join(lines)


def flipped_table(name: str, flipped: Mapping[str, Any], *, limit: int = 50) -> list[str]:
    """A MuJoCo-version variant's flipped episodes, as `mjtrial diff` lists them: the states
    whose outcome differs from the nominal model's, with the failure category in each run and
    the first logged time their trajectories part (the first `limit` listed)."""
    episodes = flipped["episodes"]
    lines = [
        "",
        f"Flipped episodes under {name}: {len(episodes)} of {flipped['n_compared']} "
        "(state, condition) outcomes differ from the nominal model's.",
    ]
    if not episodes:
        return lines
    lines += [
        "",
        f"| state | condition | nominal | {name} | where the trajectories part |",
        "| --- | --- | --- | --- | --- |",
    ]
    lines += [
        f"| {e['state_id']} | {e['condition']} | {e['nominal'] or 'success'} | "
        f"{e['variant'] or 'success'} | {describe_divergence(e.get('divergence'))} |"
        for e in episodes[:limit]
    ]
    if len(episodes) > limit:
        lines.append(f"\n({len(episodes) - limit} more in analysis/sensitivity.json)")
    return lines


def _versus_reference(c: Mapping[str, Any], parameter: str, n_states: int) -> str:
    """A value's paired difference from the reference with its interval; where every pair has
    the same difference the bootstrap interval is one point, and what the pairs were is said
    instead ("every state failed here and succeeded at the reference")."""
    if c["low"] < c["high"]:
        return f"{c['estimate']:+.3f} [{c['low']:+.3f}, {c['high']:+.3f}]"
    only_here, only_reference = c[f"only_{parameter}"], c["only_reference"]
    if not only_here and not only_reference:
        why = f"no discordant pair: each of the {n_states} states had one outcome at both values"
    elif only_reference == n_states:
        why = f"all {n_states} states failed here and succeeded at the reference"
    elif only_here == n_states:
        why = f"all {n_states} states succeeded here and failed at the reference"
    else:  # every pair the same difference cannot be anything else; said as found
        why = f"{only_here} pairs only here, {only_reference} only at the reference"
    return f"{c['estimate']:+.3f} ({why}; the bootstrap interval is that one point)"


def _odds(ratio: float) -> str:
    """An odds ratio to 3 decimals, or under 0.01 to 3 significant figures: a steep trend's
    2e-05 is not 0.000."""
    return f"{ratio:.3f}" if 0.01 <= ratio < 1000 else f"{ratio:.3g}"


def render_dose_response_section(dose_response: Mapping[str, Any], *, figure: str) -> str:
    """The report's "Dose-response" section; `figure` is the curve's path for the link."""
    d = dose_response
    parameter = d["parameter"]
    conf = pct(d["confidence"])
    bands = [b["band"] for b in d["per_value"][0]["bands"]]
    band_unit = f" ({d['band_unit']})" if d["band_unit"] else ""
    comparisons = {c[parameter]: c for c in d["comparisons"]}
    lines = [
        "## Dose-response",
        "",
        f"Success against {parameter} on the same {d['n_states']} states; rates with {conf} "
        f"Wilson intervals, pooled and per {d['band_parameter']} band{band_unit}. Each value is "
        f"compared with "
        f"{d['reference']:g} by paired difference ({d['comparison_method']['difference']}, "
        f"{d['comparison_method']['n_resamples']} resamples) and "
        f"{d['comparison_method']['test']}, p adjusted by "
        f"{d['comparison_method']['adjustment']}.",
        "",
        f"| {parameter} | pooled | " + " | ".join(bands) + " | vs reference [CI] | p (Holm) |",
        "| " + " | ".join(["---"] * (len(bands) + 4)) + " |",
    ]
    for row in d["per_value"]:
        c = comparisons.get(row[parameter])
        versus = (
            f"{_versus_reference(c, parameter, d['n_states'])} | {c['p_holm']:.3g}"
            if c
            else "reference | \u2013"
        )
        cells = [rate_cell(b) for b in row["bands"]]
        lines.append(
            f"| {row[parameter]:g} | {rate_cell(row)} | " + " | ".join(cells) + f" | {versus} |"
        )
    t = d["trend"]
    if t.get("not_estimable"):
        trend_line = f"Trend: not estimable ({t['not_estimable']}); {t['method']}."
    else:
        log = d["scale"] == "log"
        slope = t["slope_log_odds_per_log_value" if log else "slope_log_odds_per_unit_value"]
        ratio = "odds_ratio_per_doubling" if log else "odds_ratio_over_range"
        per = "per doubling" if log else f"from {min(d['values']):g} to {max(d['values']):g}"
        trend_line = (
            f"Trend: {slope:+.3f} log-odds per unit {'log ' if log else ''}{parameter} "
            f"[{t['low']:+.3f}, {t['high']:+.3f}] ({conf}; p = {t['p_value']:.3g}); odds ratio "
            f"{per} {_odds(t[ratio])} [{_odds(t[ratio + '_low'])}, {_odds(t[ratio + '_high'])}]; "
            f"{t['n_episodes']} episodes in {t['n_clusters']} state clusters; {t['method']}."
        )
    lines += [
        "",
        trend_line,
        "",
        _within_margin_sentence(d),
        "",
        f"![Success against {parameter}]({figure})",
        "",
    ]
    return "\n".join(lines)
