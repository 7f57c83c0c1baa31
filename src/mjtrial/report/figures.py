"""The report's figures, drawn from `summary.json` and the rollouts' recordings.

Figures are drawn on `matplotlib.figure.Figure` objects (no pyplot, so no global state and no
GUI backend), with fixed fonts, metadata and SVG ids, so two runs give the same bytes; each file
is stamped like every other output.
"""

from __future__ import annotations

import functools
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import Any

import matplotlib
import numpy as np
from matplotlib.colors import LinearSegmentedColormap
from matplotlib.figure import Figure
from matplotlib.transforms import offset_copy

from mjtrial import provenance
from mjtrial.files.layout import BENCHMARK_FIGURES, FIGURES
from mjtrial.report.fit import (
    figure_legend_below,
    fit_axes_labels,
    fit_text,
    fitted_legend,
    fitted_title,
)
from mjtrial.report.labels import band_parameter, failure_categories, pct, setting
from mjtrial.report.traces import SampleTraces, sample_traces
from mjtrial.task import BoundTask, Task

# Okabe-Ito colours (distinguishable with every common colour-vision deficiency), in the order
# conditions are given; yellow is left out, it vanishes on white.
CONDITION_PALETTE = ("#D55E00", "#0072B2", "#009E73", "#CC79A7", "#E69F00", "#56B4E9", "#000000")
_MARKERS = ("o", "s", "D", "^", "v", "P", "X")
_GREY = "#555555"
_SHADE = "#E4E4E4"

SINGLE_COLUMN = 3.5  # inches: one column of a two-column paper
DOUBLE_COLUMN = 7.0
# Panels per row of the traces figure: a narrower panel cannot hold its marks and legend.
TRACE_COLUMNS = 3
FIGURE_DPI = 200

# Fixed style: a bundled font (same glyphs on every machine), >= 8 pt, and a fixed SVG hash
# salt so generated ids do not change between runs.
_STYLE = {
    "font.family": "DejaVu Sans",
    "font.size": 8,
    "axes.titlesize": 9,
    "axes.labelsize": 8,
    "xtick.labelsize": 8,
    "ytick.labelsize": 8,
    "legend.fontsize": 8,
    "legend.frameon": False,
    "axes.spines.top": False,
    "axes.spines.right": False,
    "axes.linewidth": 0.8,
    "lines.linewidth": 1.2,
    "svg.fonttype": "path",
    "svg.hashsalt": "mjtrial",
    "svg.id": "mjtrial",
}
_SAVE_METADATA = {
    "png": {"Software": None},
    "svg": {"Date": None, "Creator": None},
}


def condition_colors(names: Sequence[str]) -> dict[str, str]:
    """Colour of each condition, by its position: the same condition keeps its colour in every
    figure because every figure takes the order of `summary["conditions"]`."""
    return {name: CONDITION_PALETTE[i % len(CONDITION_PALETTE)] for i, name in enumerate(names)}


def _markers(names: Sequence[str]) -> dict[str, str]:
    """A marker per condition as well, so the figures survive greyscale printing."""
    return {name: _MARKERS[i % len(_MARKERS)] for i, name in enumerate(names)}


def _figure(width: float, height: float) -> Figure:
    return Figure(figsize=(width, height), layout="constrained")


def _styled(draw: Callable[..., Figure]) -> Callable[..., Figure]:
    """Run a figure builder under the fixed style (fonts are resolved when artists are made)."""

    @functools.wraps(draw)
    def wrapper(**kwargs: Any) -> Figure:
        with matplotlib.rc_context(_STYLE):
            fig = draw(**kwargs)
            fit_axes_labels(fig)
            return fig

    return wrapper


@_styled
def figure_success_by_condition(*, summary: Mapping[str, Any], task: Task) -> Figure:
    """Success rate per condition with its Wilson interval and k/n: the headline result."""
    conditions = summary["conditions"]
    names = list(conditions)
    colors = condition_colors(names)
    fig = _figure(SINGLE_COLUMN, 2.6)
    ax = fig.add_subplot()
    for i, name in enumerate(names):
        rec = conditions[name]
        if not rec["n"]:
            continue
        rate, low, high = rec["rate"], rec["wilson_low"], rec["wilson_high"]
        ax.bar(i, rate, width=0.55, color=colors[name], alpha=0.85, zorder=2)
        ax.errorbar(
            i,
            rate,
            yerr=[[rate - low], [high - rate]],
            fmt="none",
            ecolor="black",
            elinewidth=1.0,
            capsize=4,
            zorder=3,
        )
        ax.annotate(
            f"{rec['successes']}/{rec['n']}\n{rate:.3f}",
            xy=(i, high),
            xytext=(0, 3),
            textcoords="offset points",
            ha="center",
            va="bottom",
        )
    ax.set_xticks(
        range(len(names)),
        [f"{name}\n({setting(conditions[name], task)})" for name in names],
    )
    # tick labels are redrawn from their strings: fitted, then set again
    width = 0.6 * fig.bbox.width / len(names)  # the axes hold about 3/4 of the width
    ax.set_xticks(
        range(len(names)), [fit_text(t, width=width).get_text() for t in ax.get_xticklabels()]
    )
    ax.set_xlim(-0.6, len(names) - 0.4)
    ax.set_ylim(0, 1.25)
    ax.set_yticks(np.linspace(0, 1, 6))
    ax.set_ylabel(f"Success rate ({pct(summary['confidence'])} Wilson CI)")
    ax.set_title(f"Success per condition (n = {summary['n_states']} states)")
    ax.grid(axis="y", color=_SHADE, linewidth=0.6, zorder=0)
    return fig


@_styled
def figure_success_by_band(*, summary: Mapping[str, Any], parameter: str, task: Task) -> Figure:
    """Success per band of one state parameter and condition: where the conditions differ."""
    bands = summary["bands"][parameter]
    names = list(summary["conditions"])
    colors, markers = condition_colors(names), _markers(names)
    label, unit = band_parameter(parameter, task)
    fig = _figure(SINGLE_COLUMN, 2.9)
    ax = fig.add_subplot()
    offsets = np.linspace(-0.14, 0.14, len(names)) if len(names) > 1 else np.zeros(1)
    x = np.arange(len(bands))
    for offset, name in zip(offsets, names, strict=True):
        recs = [band["conditions"][name] for band in bands]
        keep = [i for i, rec in enumerate(recs) if rec["n"]]
        rate = np.array([recs[i]["rate"] for i in keep])
        low = np.array([recs[i]["wilson_low"] for i in keep])
        high = np.array([recs[i]["wilson_high"] for i in keep])
        ax.errorbar(
            x[keep] + offset,
            rate,
            yerr=[rate - low, high - rate],
            fmt=markers[name],
            color=colors[name],
            markersize=5,
            capsize=3,
            elinewidth=1.0,
            label=f"{name} ({setting(summary['conditions'][name], task)})",
            zorder=3,
        )
    ax.set_xticks(x, [f"{band['low']:g}\u2013{band['high']:g}\nn = {band['n']}" for band in bands])
    ax.set_xlim(-0.5, len(bands) - 0.5)
    ax.set_ylim(0, 1.04)
    ax.set_yticks(np.linspace(0, 1, 6))
    ax.set_xlabel(f"{label} band ({unit})" if unit else f"{label} band")
    ax.set_ylabel(f"Success rate ({pct(summary['confidence'])} Wilson CI)")
    ax.grid(axis="y", color=_SHADE, linewidth=0.6, zorder=0)
    ax.set_title(f"Success by {label}")
    figure_legend_below(fig, handletextpad=0.3)
    return fig


def _paired_panel(
    fig: Figure,
    ax: Any,
    record: Mapping[str, Any],
    summary: Mapping[str, Any],
    task: Task,
    *,
    columns: int = 1,
    rows: int = 1,
) -> int:
    """One comparison's 2x2 table of paired outcomes on `ax`; returns its number of states."""
    treatment, baseline = record["treatment"], record["baseline"]
    counts = record["table"]
    # rows: baseline succeeds / fails; columns: treatment succeeds / fails
    cells = np.array(
        [
            [counts["both"], counts[f"only_{baseline}"]],
            [counts[f"only_{treatment}"], counts["neither"]],
        ]
    )
    names = [
        ["both succeed", f"only {baseline}\nsucceeds"],
        [f"only {treatment}\nsucceeds", "both fail"],
    ]
    n = int(cells.sum())
    # One hue (Okabe-Ito blue) from white: count is read from lightness alone.
    cmap = LinearSegmentedColormap.from_list("mjtrial_counts", ["#FFFFFF", "#0072B2"])
    ax.imshow(cells, cmap=cmap, vmin=0, vmax=max(n, 1), aspect="auto")
    for r in range(2):
        for c in range(2):
            share = cells[r, c] / n if n else 0.0
            dark = share > 0.5
            ax.text(
                c,
                r - 0.12,
                f"{cells[r, c]}",
                ha="center",
                va="center",
                fontsize=12,
                fontweight="bold",
                color="white" if dark else "black",
            )
            ax.text(
                c,
                r + 0.2,
                f"{names[r][c]}\n({share:.1%})",
                ha="center",
                va="center",
                color="white" if dark else "black",
            )
    ax.set_xticks([0, 1], ["succeeds", "fails"])
    ax.set_yticks([0, 1], ["succeeds", "fails"], rotation=90, va="center")
    fit_text(
        ax.set_xlabel(f"{treatment} ({setting(summary['conditions'][treatment], task)})"),
        width=0.8 * fig.bbox.width / columns,
    )
    fit_text(
        ax.set_ylabel(f"{baseline} ({setting(summary['conditions'][baseline], task)})"),
        height=0.7 * fig.bbox.height / rows,
    )
    ax.xaxis.set_label_position("top")
    ax.xaxis.tick_top()
    ax.tick_params(length=0)
    for spine in ax.spines.values():
        spine.set_visible(False)
    ax.set_xticks([0.5], minor=True)
    ax.set_yticks([0.5], minor=True)
    ax.grid(which="minor", color="white", linewidth=2)
    ax.tick_params(which="minor", length=0)
    return n


def _comparison_caption(record: Mapping[str, Any]) -> str:
    """Below a panel: the difference, its interval (Newcombe's named), the Holm p."""
    p = record["paired_difference"]
    interval = f"[{p['low']:+.3f}, {p['high']:+.3f}]"
    newcombe = " (Newcombe)" if "replaces" in p else ""
    role = "primary" if record["primary"] else "exploratory" if record["exploratory"] else ""
    return (
        f"{p['treatment']} - {p['baseline']}: {p['estimate']:+.3f} {interval}{newcombe}\n"
        f"Holm p = {record['mcnemar']['p_holm']:.3g}" + (f" ({role})" if role else "")
    )


@_styled
def figure_paired_outcomes(*, summary: Mapping[str, Any], task: Task) -> Figure:
    """The 2x2 table of paired outcomes of each planned comparison: the discordant cells are
    what the paired test uses. One comparison (the falsifier's alone) is one panel, as
    before; several are panels side by side, each with its difference, interval and Holm p."""
    records = summary["comparisons"]
    if len(records) == 1:
        fig = _figure(SINGLE_COLUMN, 2.9)
        n = _paired_panel(fig, fig.add_subplot(), records[0], summary, task)
        fig.suptitle(f"Paired outcomes (n = {n} states)", fontsize=9)
        return fig
    columns, rows = 2, -(-len(records) // 2)  # two panels a row: a paper's full width
    fig = _figure(DOUBLE_COLUMN, 3.3 * rows)
    axes = np.asarray(fig.subplots(rows, columns, squeeze=False)).ravel()
    for ax, record in zip(axes, records, strict=False):
        n = _paired_panel(fig, ax, record, summary, task, columns=columns, rows=rows)
        fit_text(ax.set_title(_comparison_caption(record), fontsize=8), width=0.45 * fig.bbox.width)
    for ax in axes[len(records) :]:
        ax.set_visible(False)
    fig.suptitle(
        f"Paired outcomes of the {len(records)} planned comparisons (n = {n} states)",
        fontsize=9,
    )
    return fig


@_styled
def figure_failure_categories(*, summary: Mapping[str, Any], task: Task) -> Figure:
    """Failed episodes per category and condition, zeros shown: how each condition fails."""
    failures = summary["failures"]
    names = list(summary["conditions"])
    colors = condition_colors(names)
    categories = failure_categories(summary, task.category_names())
    fig = _figure(SINGLE_COLUMN, 3.0)
    ax = fig.add_subplot()
    height = 0.8 / len(names)
    y = np.arange(len(categories))
    top = max([1, *(v for counts in failures.values() for v in counts.values())])
    for i, name in enumerate(names):
        values = [failures.get(name, {}).get(c, 0) for c in categories]
        pos = y - 0.4 + height * (i + 0.5)
        ax.barh(
            pos,
            values,
            height=height * 0.9,
            color=colors[name],
            label=f"{name} ({sum(values)}/{summary['conditions'][name]['n']} failed)",
            zorder=2,
        )
        for p, v in zip(pos, values, strict=True):
            ax.text(v + top * 0.015, p, f"{v}", va="center", ha="left")
    ax.set_yticks(
        y, [c.replace(" or ", " or\n").replace(" during ", "\nduring ") for c in categories]
    )
    ax.invert_yaxis()
    ax.set_xlim(0, top * 1.15)
    ax.set_xlabel("Failed episodes (count)")
    ax.grid(axis="x", color=_SHADE, linewidth=0.6, zorder=0)
    ax.tick_params(axis="y", length=0)
    fig.suptitle("Failures by category", fontsize=9)
    figure_legend_below(fig, handletextpad=0.4)
    return fig


def _close_groups(
    marks: Sequence[tuple[float, str]], min_gap: float
) -> list[list[tuple[float, str]]]:
    """Time-ordered marks in runs whose neighbours are less than `min_gap` apart."""
    groups: list[list[tuple[float, str]]] = []
    for mark in marks:
        if groups and mark[0] - groups[-1][-1][0] < min_gap:
            groups[-1].append(mark)
        else:
            groups.append([mark])
    return groups


def _ids(ids: Sequence[int]) -> str:
    return ", ".join(str(i) for i in ids)


def _no_trace_reason(traces: SampleTraces, record: Mapping[str, Any]) -> str:
    """Why a condition's panel has no trace: no episode ran, or none of its chosen episodes was
    recorded (the config's `recording.episodes`)."""
    if not record["n"]:
        return "No episode ran under this condition."
    missed = [f"{outcome}: states {_ids(ids)}" for outcome, ids in traces.unrecorded.items()]
    return (
        "No sample episode of this condition was recorded ("
        + "; ".join(missed)
        + "): the config's recording.episodes keeps only some episodes."
    )


@_styled
def figure_sample_traces(
    *, traces: Mapping[str, SampleTraces], summary: Mapping[str, Any], task: Task
) -> Figure:
    """The task's trace series over time for a few successes and failures per condition (the
    lowest state ids): what a failure looks like. The traces are the recordings' logged steps,
    so they are as fine as the recording rate."""
    series = task.trace_series
    names = [c for c in summary["conditions"] if c in traces]
    colors = condition_colors(names)
    columns = min(len(names), TRACE_COLUMNS)
    rows = -(-len(names) // columns)
    fig = _figure(DOUBLE_COLUMN, 2.9 * rows)
    grid = fig.subplots(rows, columns, sharex=True, sharey=True, squeeze=False)
    axes = grid.ravel()[: len(names)]
    for ax in grid.ravel()[len(names) :]:  # the last row's empty places
        ax.set_visible(False)
    for ax in axes:  # each panel has its legend below it: its own time axis too
        ax.xaxis.set_tick_params(labelbottom=True)
    end = max(float(t.time[-1]) for t in traces.values())
    panel = fig.bbox.width / columns * 0.95  # pixels each condition's panel may use
    # the legend goes below the tick labels and the axis label, whatever the axes' height
    tick = axes[0].xaxis.get_major_ticks()[0]
    below = -(
        tick.get_tick_padding()
        + tick.get_pad()
        + matplotlib.rcParams["axes.labelpad"]
        + 2.4 * matplotlib.rcParams["font.size"]
    )
    # Marks closer than a line of text share one label: "start / stop".
    line = matplotlib.rcParams["font.size"] * fig.dpi / 72 * 1.3
    min_gap = end * line / (0.8 * panel)
    for ax, name in zip(axes, names, strict=True):
        t = traces[name]
        if not t.state_ids:  # nothing to draw the protocol's marks against: say why
            fitted_title(ax, f"{name} ({setting(summary['conditions'][name], task)})", width=panel)
            ax.set_xlabel("Time (s)")
            fit_text(
                ax.text(
                    0.5,
                    0.5,
                    _no_trace_reason(t, summary["conditions"][name]),
                    transform=ax.transAxes,
                    ha="center",
                    va="center",
                    color=_GREY,
                ),
                width=0.9 * panel,
            )
            continue
        # Episodes of different conditions may end at different times: where success is judged.
        marks = sorted([*((time, label) for label, time in t.marks.items()), (t.time[-1], "end")])
        ax.axvline(float(t.time[-1]), color=_GREY, linestyle=":", linewidth=0.8, zorder=1)
        for time, _ in marks[:-1]:
            ax.axvline(time, color=_GREY, linestyle="--", linewidth=0.7, zorder=1)
        for group in _close_groups(marks, min_gap):
            ax.text(
                group[0][0],
                1.0,
                " / ".join(label for _, label in group) + " ",
                transform=ax.get_xaxis_transform(),
                ha="right",
                va="top",
                color=_GREY,
                rotation=90,
            )
        for label, level in task.trace_levels:
            ax.axhline(level, color="black", linestyle=(0, (4, 3)), linewidth=0.9, zorder=1)
            if label:
                ax.text(
                    0.01,
                    level,
                    f"{label} {level:g}",
                    transform=ax.get_yaxis_transform(),
                    ha="left",
                    va="bottom",
                    color="black",
                )
        for outcome, style, label in ((True, "-", "succeeded"), (False, (0, (1, 1.2)), "failed")):
            rows = [i for i, ok in enumerate(t.success) if ok is outcome]
            for j, row in enumerate(rows):
                ax.plot(
                    t.time,
                    t.values[row],
                    color=colors[name],
                    linestyle=style,
                    linewidth=1.3 if outcome else 1.5,
                    alpha=0.9,
                    zorder=3 if outcome else 2,
                    label=(
                        f"{label} (state{'s' if len(rows) > 1 else ''} "
                        f"{_ids([t.state_ids[r] for r in rows])})"
                        if j == 0
                        else None
                    ),
                )
        fitted_title(ax, f"{name} ({setting(summary['conditions'][name], task)})", width=panel)
        ax.set_xlabel("Time (s)")
        fitted_legend(
            ax,
            *ax.get_legend_handles_labels(),
            width=panel,
            loc="upper center",
            bbox_to_anchor=(0.5, 0.0),
            bbox_transform=offset_copy(ax.transAxes, fig=fig, y=below, units="points"),
            handlelength=2.2,
        )
    # The plot's title ends with its unit: "block position, target (m)".
    unit = series.plot.rpartition("(")[2].rstrip(")") if series.plot.endswith(")") else ""
    label = series.name.replace("_", " ").capitalize()
    for ax in grid[:, 0]:
        ax.set_ylabel(f"{label} ({unit})" if unit else label)
    axes[0].set_xlim(0, end)
    fig.suptitle(_traces_title(series.name, traces), fontsize=9)
    return fig


def _traces_title(series: str, traces: Mapping[str, SampleTraces]) -> str:
    """The traces figure's title: the recording interval of the episodes drawn, or that none
    was drawn (no interval to state when nothing was recorded)."""
    what = series.replace("_", " ").capitalize()
    intervals = sorted({round(t.log_interval * 1e3, 6) for t in traces.values() if t.state_ids})
    if not intervals:
        return f"{what}: no sample episode was recorded"
    logged = " or ".join(f"{ms:g}" for ms in intervals)
    return f"{what} in sample episodes (lowest state ids), as recorded every {logged} ms"


@_styled
def figure_performance_profile(*, summary: Mapping[str, Any]) -> Figure:
    """A benchmark's performance profiles (rliable's score distributions): for each method, the
    fraction of its (training seed, task) success rates above each threshold, with the
    stratified bootstrap band; a method that fails outright on one task shows as a step."""
    methods = list(summary["overall"])
    colors, markers = condition_colors(methods), _markers(methods)

    def rec_tasks(method: str) -> list[str]:  # a method not run on every task: its tasks
        return summary["overall"][method].get("tasks", [])

    fig = _figure(SINGLE_COLUMN, 2.6)
    ax = fig.add_subplot()
    for method in methods:
        profile = summary["overall"][method]["performance_profile"]
        taus = np.asarray(profile["taus"])
        ax.fill_between(
            taus, profile["low"], profile["high"], step="post", color=colors[method], alpha=0.2
        )
        ax.step(
            taus,
            profile["fraction"],
            where="post",
            color=colors[method],
            marker=markers[method],
            markersize=3,
            label=method + (f" ({', '.join(tasks)})" if (tasks := rec_tasks(method)) else ""),
        )
    ax.set_xlim(0, 1)
    ax.set_ylim(0, 1.02)
    ax.set_xlabel("Success rate threshold \N{GREEK SMALL LETTER TAU}")
    n_runs = len(summary["seeds"]) * len(summary["tasks"])
    runs = "each method's runs" if "not_run" in summary else f"{n_runs} runs"
    ax.set_ylabel(f"Fraction of {runs} above \N{GREEK SMALL LETTER TAU}")
    ax.set_title(f"Performance profiles ({pct(summary['intervals']['confidence'])} bands)")
    ax.grid(color=_SHADE, linewidth=0.6, zorder=0)
    ax.legend(loc="lower left")
    return fig


def write_benchmark_figures(
    *, summary: Mapping[str, Any], out_dir: Path, stamp: Mapping[str, Any]
) -> list[Path]:
    """A benchmark's figures (`mjtrial.files.layout.BENCHMARK_FIGURES`), PNG then SVG for each."""
    builders = {"performance_profile": figure_performance_profile}
    return [
        path
        for name in BENCHMARK_FIGURES
        for path in _save(
            builders[name](summary=summary), out_dir=Path(out_dir), name=name, stamp=stamp
        )
    ]


def _save(fig: Figure, *, out_dir: Path, name: str, stamp: Mapping[str, Any]) -> list[Path]:
    """Write `fig` as `<name>.png` and `<name>.svg`, stamped, under the fixed style (the SVG ids
    and font handling are read when the file is saved).

    The constrained layout runs for the first file only, and the second keeps where it put
    every axes: the same figure twice, and no third layout pass (a third of what the figures
    cost)."""
    paths = []
    with matplotlib.rc_context(_STYLE):
        for fmt, metadata in _SAVE_METADATA.items():
            path = out_dir / f"{name}.{fmt}"
            provenance.write_figure(fig, path, stamp, dpi=FIGURE_DPI, metadata=metadata)
            paths.append(path)
            fig.set_layout_engine("none")
    return paths


def write_figures(
    *,
    summary: Mapping[str, Any],
    bound: BoundTask,
    rollout_tables: Mapping[str, Path],
    recordings: Mapping[str, Sequence[Path]],
    conditions: Mapping[str, Mapping[str, float]],
    out_dir: Path,
    stamp: Mapping[str, Any],
    condition_bounds: Mapping[str, BoundTask] | None = None,
) -> list[Path]:
    """Write every figure of `mjtrial.files.layout.FIGURES` as `<out_dir>/<name>.png` and `.svg`.

    Args:
      summary: `summary.json` (`mjtrial.analysis.summarize`).
      bound: the task on the model that ran: the figures' words and the traces' series.
      rollout_tables: condition -> its rollout table, which picks the traced episodes.
      recordings: condition -> its shards' folders of recordings (`rollouts/<condition>/shard-*`
        of this run), from which the traces are read.
      conditions: condition -> its protocol parameters (config `conditions`).
      out_dir: the figures' folder.
      stamp: the provenance stamp of every file written.
      condition_bounds: condition -> its task on its own model, where it is not `bound`'s
        (`sample_traces`).

    Returns the paths written, PNG then SVG for each figure, in `FIGURES` order.
    """
    out_dir = Path(out_dir)
    task = bound.task
    figures = {
        "success_by_condition": figure_success_by_condition(summary=summary, task=task),
        "paired_outcomes": figure_paired_outcomes(summary=summary, task=task),
        "failure_categories": figure_failure_categories(summary=summary, task=task),
        "success_by_band": figure_success_by_band(
            summary=summary, parameter=next(iter(summary["bands"])), task=task
        ),
    }
    traces = sample_traces(
        bound=bound,
        rollout_tables=rollout_tables,
        recordings=recordings,
        conditions={name: conditions[name] for name in summary["conditions"]},
        condition_bounds=condition_bounds,
    )
    figures["sample_traces"] = figure_sample_traces(traces=traces, summary=summary, task=task)
    paths: list[Path] = []
    for name in FIGURES:
        paths += _save(figures[name], out_dir=out_dir, name=name, stamp=stamp)
    return paths
