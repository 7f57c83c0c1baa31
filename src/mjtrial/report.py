"""Figures and the Markdown report: the experiment as a reader of the paper sees it.

Every number in the report is formatted from `summary.json`, `manifest.json`, the config or the
model the manifest names; none is typed here, so the report cannot drift from the results.
Figures are drawn on `matplotlib.figure.Figure` objects (no pyplot, so no global state and no
GUI backend), with fixed fonts, metadata and SVG ids, so two runs give the same bytes; each file
is stamped like every other output.
"""

from __future__ import annotations

import functools
import io
import json
import os
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from mjtrial import REPO_ROOT, provenance

if TYPE_CHECKING:  # pragma: no cover
    import mujoco
    from matplotlib.figure import Figure

__all__ = [
    "CONDITION_PALETTE",
    "FIGURE_NAMES",
    "HeightTraces",
    "condition_colors",
    "cube_height_traces",
    "figure_cube_height",
    "figure_failure_categories",
    "figure_paired_outcomes",
    "figure_success_by_band",
    "figure_success_by_condition",
    "render_report",
    "write_figures",
    "write_report",
]

# Okabe-Ito colours (distinguishable with every common colour-vision deficiency), in the order
# conditions are given; yellow is left out, it vanishes on white.
CONDITION_PALETTE = ("#D55E00", "#0072B2", "#009E73", "#CC79A7", "#E69F00", "#56B4E9", "#000000")
_MARKERS = ("o", "s", "D", "^", "v", "P", "X")
_GREY = "#555555"
_SHADE = "#E4E4E4"

SINGLE_COLUMN = 3.5  # inches: one column of a two-column paper
DOUBLE_COLUMN = 7.0
FIGURE_DPI = 200
FIGURE_NAMES = (
    "success_by_condition",
    "success_by_mass",
    "paired_outcomes",
    "failure_categories",
    "cube_height",
)
# Episodes of each outcome per condition drawn in the cube-height figure.
TRACES_PER_OUTCOME = 3

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

# Units of the state parameters a band table can sort by (mjtrial.states.STATE_PARAMETERS),
# and of the failure taxonomy's thresholds (mjtrial.taxonomy.Thresholds).
_UNITS = {"dx": "m", "dy": "m", "yaw": "rad", "mass": "kg"}
_TAXONOMY_UNITS = {
    "lifted_height": "m",
    "slip_distance": "m",
    "workspace_radius": "m",
    "max_tilt": "rad",
}


# --------------------------------------------------------------------------------------------
# Small helpers
# --------------------------------------------------------------------------------------------


def condition_colors(names: Sequence[str]) -> dict[str, str]:
    """Colour of each condition, by its position: the same condition keeps its colour in every
    figure because every figure takes the order of `summary["conditions"]`."""
    return {name: CONDITION_PALETTE[i % len(CONDITION_PALETTE)] for i, name in enumerate(names)}


def _markers(names: Sequence[str]) -> dict[str, str]:
    """A marker per condition as well, so the figures survive greyscale printing."""
    return {name: _MARKERS[i % len(_MARKERS)] for i, name in enumerate(names)}


def _band_parameter(parameter: str) -> tuple[str, str]:
    """(readable name, unit) of a band parameter such as `mass` or `abs_dx`."""
    base = parameter.removeprefix("abs_")
    label = f"|{base}|" if parameter.startswith("abs_") else base
    return label, _UNITS.get(base, "")


def _pct(confidence: float) -> str:
    return f"{confidence * 100:g}%"


def _rate_cell(rec: Mapping[str, Any]) -> str:
    """`k/n rate [low, high]`, the one format of a success rate in the report."""
    if not rec["n"]:
        return "no states"
    return (
        f"{rec['successes']}/{rec['n']} {rec['rate']:.3f} "
        f"[{rec['wilson_low']:.3f}, {rec['wilson_high']:.3f}]"
    )


def _interval(low: float, high: float, *, signed: bool = False) -> str:
    return f"[{low:+.3f}, {high:+.3f}]" if signed else f"[{low:.3f}, {high:.3f}]"


def _figure(width: float, height: float) -> Figure:
    from matplotlib.figure import Figure

    return Figure(figsize=(width, height), layout="constrained")


def _figure_bytes(fig: Figure, fmt: str) -> bytes:
    """The figure's bytes in `fmt` (png or svg), rendered under the fixed style."""
    import matplotlib

    buffer = io.BytesIO()
    with matplotlib.rc_context(_STYLE):
        fig.savefig(buffer, format=fmt, dpi=FIGURE_DPI, metadata=_SAVE_METADATA[fmt])
    return buffer.getvalue()


def _styled(draw: Any) -> Any:
    """Run a figure builder under the fixed style (fonts are resolved when artists are made)."""

    @functools.wraps(draw)
    def wrapper(**kwargs: Any) -> Figure:
        import matplotlib

        with matplotlib.rc_context(_STYLE):
            return draw(**kwargs)

    return wrapper


# --------------------------------------------------------------------------------------------
# Figures
# --------------------------------------------------------------------------------------------


@_styled
def figure_success_by_condition(*, summary: Mapping[str, Any]) -> Figure:
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
        [f"{name}\n({conditions[name]['lift_time']:g} s lift)" for name in names],
    )
    ax.set_xlim(-0.6, len(names) - 0.4)
    ax.set_ylim(0, 1.25)
    ax.set_yticks(np.linspace(0, 1, 6))
    ax.set_ylabel(f"Success rate ({_pct(summary['confidence'])} Wilson CI)")
    ax.set_title(f"Success per condition (n = {summary['n_states']} states)")
    ax.grid(axis="y", color=_SHADE, linewidth=0.6, zorder=0)
    return fig


@_styled
def figure_success_by_band(*, summary: Mapping[str, Any], parameter: str = "mass") -> Figure:
    """Success per band of one state parameter and condition: where the conditions differ."""
    bands = summary["bands"][parameter]
    names = list(summary["conditions"])
    colors, markers = condition_colors(names), _markers(names)
    label, unit = _band_parameter(parameter)
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
            label=f"{name} ({summary['conditions'][name]['lift_time']:g} s lift)",
            zorder=3,
        )
    ax.set_xticks(x, [f"{band['low']:g}\u2013{band['high']:g}\nn = {band['n']}" for band in bands])
    ax.set_xlim(-0.5, len(bands) - 0.5)
    ax.set_ylim(0, 1.04)
    ax.set_yticks(np.linspace(0, 1, 6))
    ax.set_xlabel(f"Cube {label} band ({unit})" if unit else f"{label} band")
    ax.set_ylabel(f"Success rate ({_pct(summary['confidence'])} Wilson CI)")
    ax.grid(axis="y", color=_SHADE, linewidth=0.6, zorder=0)
    ax.set_title(f"Success by {label}")
    # Below the axes: no data point can sit under it.
    fig.legend(loc="outside lower center", ncols=min(len(names), 3), handletextpad=0.3)
    return fig


@_styled
def figure_paired_outcomes(*, summary: Mapping[str, Any]) -> Figure:
    """The 2x2 table of paired outcomes: the discordant cells are what the paired test uses."""
    from matplotlib.colors import LinearSegmentedColormap

    paired = summary["paired_difference"]
    treatment, baseline = paired["treatment"], paired["baseline"]
    counts = summary["discordant"]
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
    fig = _figure(SINGLE_COLUMN, 2.9)
    ax = fig.add_subplot()
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
    ax.set_xlabel(f"{treatment} ({summary['conditions'][treatment]['lift_time']:g} s lift)")
    ax.set_ylabel(f"{baseline} ({summary['conditions'][baseline]['lift_time']:g} s lift)")
    ax.xaxis.set_label_position("top")
    ax.xaxis.tick_top()
    ax.tick_params(length=0)
    for spine in ax.spines.values():
        spine.set_visible(False)
    ax.set_xticks([0.5], minor=True)
    ax.set_yticks([0.5], minor=True)
    ax.grid(which="minor", color="white", linewidth=2)
    ax.tick_params(which="minor", length=0)
    fig.suptitle(f"Paired outcomes (n = {n} states)", fontsize=9)
    return fig


def _failure_categories(summary: Mapping[str, Any]) -> list[str]:
    """Every category of the taxonomy, in its order, plus any other named in the summary."""
    from mjtrial.taxonomy import FailureCategory

    categories = [c.value for c in FailureCategory]
    for counts in summary["failures"].values():
        categories += [c for c in counts if c not in categories]
    return categories


@_styled
def figure_failure_categories(*, summary: Mapping[str, Any]) -> Figure:
    """Failed episodes per category and condition, zeros shown: how each condition fails."""
    failures = summary["failures"]
    names = list(summary["conditions"])
    colors = condition_colors(names)
    categories = _failure_categories(summary)
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
    fig.legend(loc="outside lower center", ncols=min(len(names), 3), handletextpad=0.4)
    return fig


@dataclass(frozen=True)
class HeightTraces:
    """Cube height of a few re-simulated episodes of one condition.

    Attributes:
      condition: the condition's name.
      lift_time: its lift duration, s.
      time: (n_steps,) simulated time after each step, s.
      height: (n_episodes, n_steps) cube centre height, m.
      state_ids: (n_episodes,) the episodes' state ids.
      success: (n_episodes,) the episodes' recorded outcomes.
      close_start, lift_start, lift_end: phase boundaries, s.
    """

    condition: str
    lift_time: float
    time: np.ndarray
    height: np.ndarray
    state_ids: tuple[int, ...]
    success: tuple[bool, ...]
    close_start: float
    lift_start: float
    lift_end: float


def _chosen_episodes(table_path: Path, per_outcome: int) -> list[tuple[int, bool]]:
    """(state_id, success) of the lowest-id successes and failures: a choice that is fixed in
    advance, not a pick of telling examples."""
    import pyarrow.parquet as pq

    table = pq.read_table(table_path, columns=["state_id", "success"])
    ids = np.asarray(table.column("state_id").to_numpy(), dtype=np.int64)
    success = np.asarray(table.column("success").to_numpy(), dtype=bool)
    order = np.argsort(ids, kind="stable")
    ids, success = ids[order], success[order]
    chosen = [*ids[success][:per_outcome], *ids[~success][:per_outcome]]
    return [(int(i), bool(success[ids == i][0])) for i in sorted(chosen)]


def cube_height_traces(
    *,
    states_path: Path,
    rollout_tables: Mapping[str, Path],
    model_file: Path,
    lift_times: Mapping[str, float],
    per_outcome: int = TRACES_PER_OUTCOME,
) -> dict[str, HeightTraces]:
    """Re-simulate up to `per_outcome` successes and failures of each condition with the engine.

    Trajectories are not stored, and a dozen episodes cost well under a second. Raises
    ValueError when a re-simulated outcome differs from the recorded one: the figure would
    otherwise label a trajectory with an outcome it did not have.
    """
    import pyarrow.parquet as pq

    from mjtrial.protocol import Phase, control_sequence
    from mjtrial.simulate import cube_height, episode_outcomes, iter_episode_batches, load_model
    from mjtrial.states import states_from_table

    model = load_model(model_file)
    dt = float(model.opt.timestep)
    by_id = {
        s.state_id: s
        for s in states_from_table(pq.read_table(states_path), source=str(states_path))
    }
    traces = {}
    for name, table_path in rollout_tables.items():
        lift_time = float(lift_times[name])
        chosen = _chosen_episodes(Path(table_path), per_outcome)
        states = [by_id[i] for i, _ in chosen]
        _, phase = control_sequence(lift_time, timestep=dt)
        lift = np.flatnonzero(phase == Phase.LIFT)
        heights: list[np.ndarray] = []
        for batch in iter_episode_batches(model, states, lift_time=lift_time, nthread=1):
            outcome = episode_outcomes(model, batch, lift_time=lift_time)
            for state, ok in zip(batch.states, outcome["success"], strict=True):
                recorded = dict(chosen)[state.state_id]
                if bool(ok) != recorded:
                    raise ValueError(
                        f"{table_path}: state {state.state_id} re-simulates to success={bool(ok)}"
                        f" but was recorded as success={recorded}; the rollouts are stale"
                    )
            heights.append(cube_height(model, batch.physics))
        n_steps = len(phase)
        traces[name] = HeightTraces(
            condition=name,
            lift_time=lift_time,
            # The step clock rather than the state's time, which freezes if a warning halts.
            time=(np.arange(n_steps) + 1) * dt,
            height=np.concatenate(heights) if heights else np.empty((0, n_steps)),
            state_ids=tuple(i for i, _ in chosen),
            success=tuple(ok for _, ok in chosen),
            close_start=float(np.flatnonzero(phase == Phase.CLOSE)[0] * dt),
            lift_start=float(lift[0] * dt),
            lift_end=float((lift[-1] + 1) * dt),
        )
    return traces


def _ids(ids: Sequence[int]) -> str:
    return ", ".join(str(i) for i in ids)


@_styled
def figure_cube_height(
    *,
    traces: Mapping[str, HeightTraces],
    success_height: float,
    condition_order: Sequence[str] | None = None,
) -> Figure:
    """Cube height over time for a few successes and failures per condition: what a fast-lift
    failure looks like (the cube stays behind while the gripper rises)."""
    names = list(condition_order or traces)
    colors = condition_colors(names)
    fig = _figure(DOUBLE_COLUMN, 2.9)
    axes = fig.subplots(1, len(names), sharex=True, sharey=True, squeeze=False)[0]
    end = max(float(t.time[-1] - t.lift_start) for t in traces.values())
    start = min(float(t.close_start - t.lift_start) for t in traces.values())
    top = max(
        [success_height, *(float(np.nanmax(t.height)) for t in traces.values() if t.height.size)]
    )
    for ax, name in zip(axes, names, strict=True):
        t = traces[name]
        x = t.time - t.lift_start
        ax.axvspan(0, t.lift_end - t.lift_start, color=_SHADE, zorder=0, linewidth=0)
        ax.text(
            (t.lift_end - t.lift_start) / 2,
            1.0,
            "lift",
            transform=ax.get_xaxis_transform(),
            ha="center",
            va="top",
            color=_GREY,
        )
        # Episodes of different conditions end at different times: mark where success is judged.
        judged = float(t.time[-1] - t.lift_start)
        ax.axvline(judged, color=_GREY, linestyle=":", linewidth=0.8, zorder=1)
        ax.text(
            judged,
            1.0,
            "judged ",
            transform=ax.get_xaxis_transform(),
            ha="right",
            va="top",
            color=_GREY,
        )
        ax.axhline(success_height, color="black", linestyle=(0, (4, 3)), linewidth=0.9, zorder=1)
        # At the right end: lifted cubes sit above the line there, dropped ones far below.
        ax.text(
            end,
            success_height,
            f"success height {success_height:g} m",
            ha="right",
            va="bottom",
            color="black",
        )
        for outcome, style, label in ((True, "-", "succeeded"), (False, (0, (1, 1.2)), "failed")):
            rows = [i for i, ok in enumerate(t.success) if ok is outcome]
            for j, row in enumerate(rows):
                ax.plot(
                    x,
                    t.height[row],
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
        ax.set_title(f"{name} ({t.lift_time:g} s lift)")
        ax.set_xlabel("Time from lift onset (s)")
        ax.legend(loc="upper center", bbox_to_anchor=(0.5, -0.22), ncols=1, handlelength=2.2)
    axes[0].set_ylabel("Cube height (m)")
    axes[0].set_xlim(start, end)
    axes[0].set_ylim(0, top * 1.2)
    fig.suptitle("Cube height in sample episodes (lowest state ids)", fontsize=9)
    return fig


def _save(fig: Figure, *, out_dir: Path, name: str, stamp: Mapping[str, Any]) -> list[Path]:
    png, svg = out_dir / f"{name}.png", out_dir / f"{name}.svg"
    provenance.write_png(_figure_bytes(fig, "png"), png, stamp)
    provenance.write_svg(_figure_bytes(fig, "svg"), svg, stamp)
    return [png, svg]


def write_figures(
    *,
    summary: Mapping[str, Any],
    states_path: Path,
    rollout_tables: Mapping[str, Path],
    model_file: Path,
    lift_times: Mapping[str, float],
    out_dir: Path,
    stamp: Mapping[str, Any],
) -> list[Path]:
    """Write every figure of `FIGURE_NAMES` as `<out_dir>/<name>.png` and `.svg`, stamped.

    Returns the paths written, PNG then SVG for each figure, in `FIGURE_NAMES` order.
    """
    from mjtrial.protocol import PROTOCOL

    out_dir = Path(out_dir)
    traces = cube_height_traces(
        states_path=states_path,
        rollout_tables=rollout_tables,
        model_file=model_file,
        lift_times=lift_times,
    )
    figures = {
        "success_by_condition": figure_success_by_condition(summary=summary),
        "success_by_mass": figure_success_by_band(summary=summary, parameter="mass"),
        "paired_outcomes": figure_paired_outcomes(summary=summary),
        "failure_categories": figure_failure_categories(summary=summary),
        "cube_height": figure_cube_height(
            traces=traces,
            success_height=PROTOCOL.success_height,
            condition_order=[c for c in summary["conditions"] if c in traces],
        ),
    }
    paths: list[Path] = []
    for name in FIGURE_NAMES:
        paths += _save(figures[name], out_dir=out_dir, name=name, stamp=stamp)
    return paths


# --------------------------------------------------------------------------------------------
# Report
# --------------------------------------------------------------------------------------------

_CAPTIONS = {
    "success_by_condition": "Success rate per condition",
    "success_by_mass": "Success rate by cube mass band",
    "paired_outcomes": "Paired outcomes of the same initial states",
    "failure_categories": "Failed episodes by category",
    "cube_height": "Cube height over time in sample episodes",
}
_RESULT_FIGURES = ("success_by_condition", "success_by_mass", "paired_outcomes")
_FAILURE_FIGURES = ("failure_categories", "cube_height")

_MISTAKE_WHY = {
    "nominal_state": (
        "One episode per condition: its interval, {widest}, covers most of the possible rates, "
        "so the shortcut cannot separate the conditions; and the nominal state (centred, "
        "upright, mass as compiled) is no sample of the offsets, yaws and masses the "
        "evaluation draws."
    ),
    "first_k": (
        "{k} states give intervals {ratio:.1f} times as wide as the {n} states (mean width "
        "{width_k:.3f} against {width_n:.3f}), and the first states are just a smaller sample "
        "of the same seed, not a better one: the rates move by chance alone."
    ),
}

_SCOPE_LIMITS = (
    "**One model.** A single gantry gripper with one pad geometry, grip force limit and contact "
    "parametrisation; another gripper may trade speed for success differently.",
    "**One simulator version.** Every number comes from the MuJoCo version listed under "
    "Reproduction, with one timestep, integrator and contact model; whether the effect survives "
    "other solver and contact settings is a planned ablation, not a result.",
    "**Open-loop protocol.** The lift follows a fixed control sequence with no feedback; a "
    "controller that reacts to slip could close the gap between the conditions.",
    "**Mass-only randomization.** The cube's mass varies while its inertia stays as compiled, "
    "and size, friction and shape are fixed; the result is about this distribution of "
    "offsets, yaws and masses only.",
    "**Only the lift durations that ran.** The comparison says nothing about durations in "
    "between (the dose-response curve is a planned ablation), nor about a real robot.",
)


def _geom_name(model: mujoco.MjModel, i: int) -> str:
    import mujoco

    return mujoco.mj_id2name(model, mujoco.mjtObj.mjOBJ_GEOM, i) or f"geom {i}"


def _contact_table(model: mujoco.MjModel) -> list[str]:
    """One row per geom that can collide: what sets the friction budget of the grasp."""
    rows = [
        "| geom | condim | friction (sliding, torsional, rolling) | solref | solimp |",
        "| --- | --- | --- | --- | --- |",
    ]
    for i in range(model.ngeom):
        if not (model.geom_contype[i] or model.geom_conaffinity[i]):
            continue
        friction = ", ".join(f"{v:g}" for v in model.geom_friction[i])
        solref = ", ".join(f"{v:g}" for v in model.geom_solref[i])
        solimp = ", ".join(f"{v:g}" for v in model.geom_solimp[i])
        rows.append(
            f"| `{_geom_name(model, i)}` | {model.geom_condim[i]} | {friction} | {solref} "
            f"| {solimp} |"
        )
    return rows


def _actuator_limits(model: mujoco.MjModel) -> str:
    """Force limits of the force-limited actuators (N: they drive slide joints or a tendon)."""
    import mujoco

    parts = []
    for i in range(model.nu):
        if not model.actuator_forcelimited[i]:
            continue
        name = mujoco.mj_id2name(model, mujoco.mjtObj.mjOBJ_ACTUATOR, i) or f"actuator {i}"
        low, high = model.actuator_forcerange[i]
        parts.append(f"`{name}` [{low:g}, {high:g}]")
    return ", ".join(parts) if parts else "none"


def _load_reported_model(manifest: Mapping[str, Any], repo_root: Path) -> mujoco.MjModel:
    """The model the manifest names, refusing a file whose hash differs from the one that ran."""
    import mujoco

    path = Path(repo_root) / manifest["model"]["path"]
    sha = provenance.model_sha256(path)
    if sha != manifest["model"]["sha256"]:
        raise ValueError(
            f"{path}: sha256 {sha} differs from the manifest's {manifest['model']['sha256']}; "
            "the report would describe a model other than the one that ran"
        )
    return mujoco.MjModel.from_xml_path(str(path))


def _code_state(manifest: Mapping[str, Any]) -> str:
    """Commit(s) the outputs were produced from, as recorded in their stamps."""
    stamps = list(manifest.get("stamps", {}).values())
    if isinstance(manifest.get("provenance"), Mapping):
        stamps.append(manifest["provenance"])
    gits = [s.get("git", {}) for s in stamps]
    available = [g for g in gits if g.get("available")]
    if not available:
        reasons = sorted({g.get("reason", "no git record") for g in gits}) or ["no stamps"]
        return f"not a git repository ({'; '.join(reasons)})"
    states = sorted({(g["commit"], bool(g.get("dirty")), g.get("diff_sha256")) for g in available})
    parts = [
        f"`{commit}`"
        + (f" **dirty** (uncommitted changes, diff sha256 `{diff}`)" if dirty else " (clean)")
        for commit, dirty, diff in states
    ]
    text = "; ".join(parts)
    if len(states) > 1:
        text = "**outputs come from more than one code state**: " + text
    if len(available) < len(gits):
        text += "; some outputs were produced outside a git repository"
    return text


def _cell(value: Any) -> str:
    # A bare "|" (as in the band name "|dx|") would end the cell.
    return str(value).replace("|", "\\|")


def _table(header: Sequence[str], rows: Sequence[Sequence[Any]]) -> list[str]:
    lines = ["| " + " | ".join(_cell(h) for h in header) + " |", "|" + " --- |" * len(header)]
    lines += ["| " + " | ".join(_cell(c) for c in row) + " |" for row in rows]
    return lines


def _figure_lines(names: Sequence[str], figures: Mapping[str, str]) -> list[str]:
    lines = []
    for name in names:
        if name in figures:
            svg = str(Path(figures[name]).with_suffix(".svg").as_posix())
            lines += [
                f"![{_CAPTIONS.get(name, name)}]({figures[name]})",
                "",
                f"*{_CAPTIONS.get(name, name)}* ([SVG]({svg})).",
                "",
            ]
    return lines


def _setup(
    summary: Mapping[str, Any],
    config: Mapping[str, Any],
    manifest: Mapping[str, Any],
    model: mujoco.MjModel,
) -> list[str]:
    import numpy as np

    from mjtrial.states import STATE_PARAMETERS

    m = manifest["model"]
    states = config["states"]
    bitgen = type(np.random.default_rng(0).bit_generator).__name__
    lines = [
        "## Setup",
        "",
        f"- Simulator: MuJoCo {manifest['versions']['mujoco']}.",
        f"- Model: `{m['path']}`, sha256 `{m['sha256']}`.",
        f"- Solver: timestep {m['timestep']:g} s, integrator {m['integrator']}, "
        f"friction cone {m['cone']}, impratio {m['impratio']:g}.",
        f"- Actuator force limits (N): {_actuator_limits(model)}.",
        "- Contact parameters of the colliding geoms (read from the compiled model):",
        "",
        *_contact_table(model),
        "",
        "Conditions (each evaluation state runs under every condition: a paired design):",
        "",
        *_table(
            ["condition", "lift time (s)"],
            [[name, f"{c['lift_time']:g}"] for name, c in config["conditions"].items()],
        ),
        "",
        f"Initial states: n = {states['n']}, drawn with numpy's `default_rng({states['seed']})` "
        f"({bitgen}), one uniform draw of n values per parameter in the order "
        f"{', '.join(STATE_PARAMETERS)}:",
        "",
        *_table(
            ["parameter", "low", "high", "unit"],
            [
                [p, f"{states['ranges'][p][0]:g}", f"{states['ranges'][p][1]:g}", _UNITS.get(p, "")]
                for p in STATE_PARAMETERS
                if p in states["ranges"]
            ],
        ),
        "",
        f"Development states came from a different seed, {states['development_seed']}, used only "
        "to calibrate the model; the states stage refuses a configuration whose development and "
        "evaluation states share a state, so no reported number comes from a tuning state.",
    ]
    plan = summary.get("sample_size")
    if plan:
        met = "met" if plan["met"] else "**not met**"
        lines += [
            "",
            f"Sample size: n = {plan['n']}; the design's plan needs {plan['required']} states for "
            f"a {_pct(summary['confidence'])} half-width of {plan['target_halfwidth']:g} at worst"
            f": {met}.",
        ]
    return lines


def _metric(summary: Mapping[str, Any], manifest: Mapping[str, Any]) -> list[str]:
    success = manifest["success_definition"]
    paired = summary["paired_difference"]
    conf = _pct(summary["confidence"])
    return [
        "## Metric",
        "",
        f"- Success: the cube's centre is above {success['cube_height_above_m']:g} m "
        f"{success['judged']}.",
        "- Each episode's outcome is binary (1 = success). A condition's success rate is the mean "
        f"over its n = {summary['n_states']} evaluation states (the per-task mean; this "
        "experiment has one task).",
        f"- Success rates carry {conf} Wilson score intervals.",
        f"- Paired difference: the mean over states of success({paired['treatment']}) - "
        f"success({paired['baseline']}), with a {_pct(paired['confidence'])} interval by "
        f"{paired['method']} ({paired['n_resamples']} resamples, seed {paired['seed']}).",
        f"- Discordant pairs: {summary['mcnemar']['method']}.",
    ]


def _band_section(summary: Mapping[str, Any], parameter: str, names: Sequence[str]) -> list[str]:
    label, unit = _band_parameter(parameter)
    conditions = summary["conditions"]
    rows = [
        [f"{b['band']}", b["n"], *(_rate_cell(b["conditions"][name]) for name in names)]
        for b in summary["bands"][parameter]
    ]
    rows.append(
        ["all (pooled)", summary["n_states"], *(_rate_cell(conditions[name]) for name in names)]
    )
    head = f"{label} band ({unit})" if unit else f"{label} band"
    return [
        f"Success by {label} band (k/n, rate, {_pct(summary['confidence'])} Wilson interval):",
        "",
        *_table([head, "n", *names], rows),
        "",
    ]


def _results(
    summary: Mapping[str, Any], figures: Mapping[str, str], names: Sequence[str]
) -> list[str]:
    conf = _pct(summary["confidence"])
    conditions = summary["conditions"]
    paired = summary["paired_difference"]
    treatment, baseline = paired["treatment"], paired["baseline"]
    d = summary["discordant"]
    lines = [
        "## Results",
        "",
        *_table(
            [
                "condition",
                "lift time (s)",
                "successes",
                "success rate",
                f"{conf} Wilson interval",
                "unhealthy episodes",
            ],
            [
                [
                    name,
                    f"{rec['lift_time']:g}",
                    f"{rec['successes']}/{rec['n']}",
                    f"{rec['rate']:.3f}" if rec["n"] else "-",
                    _interval(rec["wilson_low"], rec["wilson_high"]) if rec["n"] else "-",
                    rec["unhealthy"],
                ]
                for name, rec in conditions.items()
            ],
        ),
        "",
        f"Paired difference {treatment} - {baseline}: **{paired['estimate']:+.3f}**, "
        f"{_pct(paired['confidence'])} interval "
        f"{_interval(paired['low'], paired['high'], signed=True)} ({paired['method']}, "
        f"{paired['n_resamples']} resamples, seed {paired['seed']}).",
        "",
        "Paired outcomes (number of initial states):",
        "",
        *_table(
            ["", f"{treatment} succeeds", f"{treatment} fails"],
            [
                [f"**{baseline} succeeds**", d["both"], d[f"only_{baseline}"]],
                [f"**{baseline} fails**", d[f"only_{treatment}"], d["neither"]],
            ],
        ),
        "",
        f"Discordant pairs: {d[f'only_{treatment}']} states succeed only under {treatment}, "
        f"{d[f'only_{baseline}']} only under {baseline}; {summary['mcnemar']['method']} "
        f"p = {summary['mcnemar']['p_value']:.3g}.",
        "",
    ]
    for parameter in summary["bands"]:
        lines += _band_section(summary, parameter, names)
    pooled = summary.get("pooled_over")
    if pooled:
        n = summary["n_states"]
        dist = ", ".join(f"{b['band']}: {b['n']} ({b['n'] / n:.1%})" for b in pooled["mass_bands"])
        lines += [
            f"Pooling caveat: {pooled['what']}. The evaluation's mass distribution (kg): {dist}. "
            "A pooled rate is the per-band rates weighted by these shares, so another mass "
            "distribution gives another pooled rate; the per-band rates are what carries over.",
            "",
        ]
    lines += _figure_lines(_RESULT_FIGURES, figures)
    other = [n for n in figures if n not in _RESULT_FIGURES + _FAILURE_FIGURES]
    lines += _figure_lines(other, figures)
    return lines


def _failure_analysis(
    summary: Mapping[str, Any],
    config: Mapping[str, Any],
    figures: Mapping[str, str],
    names: Sequence[str],
) -> list[str]:
    failures = summary["failures"]
    categories = _failure_categories(summary)
    rows = [[c, *(failures[name].get(c, 0) for name in names)] for c in categories]
    rows.append(["**all failures**", *(sum(failures[name].values()) for name in names)])
    thresholds = ", ".join(
        f"{k} {v:g} {_TAXONOMY_UNITS.get(k, '')}".rstrip()
        for k, v in config.get("failure_taxonomy", {}).items()
    )
    lines = [
        "## Failure analysis",
        "",
        "Each failed episode gets exactly one category, the first that applies in the order "
        f"below (`mjtrial.taxonomy`; thresholds from the config: {thresholds}).",
        "",
        *_table(["category", *names], rows),
        "",
    ]
    return lines + _figure_lines(_FAILURE_FIGURES, figures)


def _falsifier(summary: Mapping[str, Any]) -> list[str]:
    f = summary["falsifier"]
    conf = _pct(summary["paired_difference"]["confidence"])
    return [
        "## Falsifier",
        "",
        f"Written before the data: the hypothesis is refuted when the lower bound of the {conf} "
        f"interval of {f['statistic']} ({f['treatment']} - {f['baseline']}) is at or below "
        f"{f['threshold']:g}.",
        "",
        f"Verdict: **{f['verdict'].upper()}**.",
        "",
        f"> {f['reason']}",
    ]


def _mistakes(summary: Mapping[str, Any], names: Sequence[str]) -> list[str]:
    conf = _pct(summary["confidence"])
    conditions = summary["conditions"]
    lines = [
        "## Two classic evaluation mistakes, reproduced",
        "",
        f"Success rate with {conf} Wilson interval under each shortcut, beside the real result:",
        "",
    ]
    rows = [
        [f"{summary['n_states']} evaluation states (the result)"]
        + [_rate_cell(conditions[name]) for name in names]
    ]
    for mistake in summary["mistakes"].values():
        rows.append([mistake["what"], *(_rate_cell(mistake["conditions"][n]) for n in names)])
    lines += [*_table(["evaluated on", *names], rows), ""]

    def width(rec: Mapping[str, Any]) -> float:
        return rec["wilson_high"] - rec["wilson_low"]

    for key, mistake in summary["mistakes"].items():
        why = _MISTAKE_WHY.get(key)
        if why is None:
            continue
        recs = [mistake["conditions"][n] for n in names if mistake["conditions"][n]["n"]]
        full = [conditions[n] for n in names if conditions[n]["n"]]
        if not recs or not full:
            continue
        widest = max(recs, key=width)
        width_k = float(np.mean([width(r) for r in recs]))
        width_n = float(np.mean([width(r) for r in full]))
        text = why.format(
            widest=_interval(widest["wilson_low"], widest["wilson_high"]),
            k=mistake.get("k", recs[0]["n"]),
            n=summary["n_states"],
            ratio=width_k / width_n if width_n else float("inf"),
            width_k=width_k,
            width_n=width_n,
        )
        lines += [f"- *{mistake['what'][0].upper()}{mistake['what'][1:]}*: {text}"]
    return lines


def _reproduction(manifest: Mapping[str, Any], manifest_path: str | None) -> list[str]:
    seeds = ", ".join(f"{k} {v}" for k, v in manifest.get("seeds", {}).items())
    lines = [
        "## Reproduction",
        "",
        f"- Code: {_code_state(manifest)}.",
        f"- Command: `{manifest['rerun']['command']}` (from the repository root; the full config "
        "is copied into the manifest under `rerun.config`).",
    ]
    if manifest_path:
        lines.append(f"- Manifest: `{manifest_path}` (every output's provenance stamp).")
    lines += [
        f"- Seeds: {seeds}.",
        "",
        *_table(["package", "version"], [[k, v] for k, v in manifest["versions"].items()]),
    ]
    return lines


def render_report(
    *,
    summary: Mapping[str, Any],
    config: Mapping[str, Any],
    manifest: Mapping[str, Any],
    figures: Mapping[str, str],
    repo_root: Path = REPO_ROOT,
    manifest_path: str | None = None,
) -> str:
    """The report as Markdown, every number formatted from its arguments (or the model).

    Args:
      summary: `summary.json` (`mjtrial.analysis.summarize`).
      config: the experiment's config (the design record).
      manifest: `manifest.json`; its model path is read relative to `repo_root`, and the file
        must still have the sha256 the manifest recorded.
      figures: figure name -> path of its PNG relative to the report's folder.
      manifest_path: where the manifest lives, as the reader should see it.
    """
    model = _load_reported_model(manifest, Path(repo_root))
    names = list(summary["conditions"])
    design = config.get("design", {})
    lines = [f"# {config.get('experiment', manifest.get('experiment', 'Experiment'))}", ""]
    if design.get("question"):
        lines += [f"**Question.** {design['question']}", ""]
    if design.get("hypothesis"):
        lines += [f"**Hypothesis.** {design['hypothesis']}", ""]
    sections = [
        _setup(summary, config, manifest, model),
        _metric(summary, manifest),
        _results(summary, figures, names),
        _failure_analysis(summary, config, figures, names),
        _falsifier(summary),
        _mistakes(summary, names),
        ["## What this experiment does not show", "", *(f"- {s}" for s in _SCOPE_LIMITS)],
        _reproduction(manifest, manifest_path),
    ]
    for section in sections:
        while section and section[-1] == "":
            section = section[:-1]
        lines += [*section, ""]
    return "\n".join(lines)


def _relative(path: Path, start: Path) -> str:
    return Path(os.path.relpath(Path(path).resolve(), Path(start).resolve())).as_posix()


def _shown_path(path: Path, *, repo_root: Path, report_dir: Path) -> str:
    """`path` relative to the repository when inside it, else to the report's folder."""
    try:
        return Path(path).resolve().relative_to(Path(repo_root).resolve()).as_posix()
    except ValueError:
        return _relative(path, report_dir)


def write_report(
    *,
    summary_path: Path,
    config: Mapping[str, Any],
    manifest_path: Path,
    figure_paths: Sequence[Path],
    output: Path,
    stamp: Mapping[str, Any],
    repo_root: Path = REPO_ROOT,
) -> str:
    """Write `report.md` (stamped); figure links are relative to the report's folder.

    `figure_paths` may hold each figure's PNG and SVG; the PNG is embedded, the SVG linked.
    Returns the Markdown written (without its front matter).
    """
    output = Path(output)
    summary = json.loads(Path(summary_path).read_text(encoding="utf-8"))
    manifest = json.loads(Path(manifest_path).read_text(encoding="utf-8"))
    figures = {
        Path(p).stem: _relative(Path(p), output.parent)
        for p in figure_paths
        if Path(p).suffix.lower() == ".png"
    }
    text = render_report(
        summary=summary,
        config=config,
        manifest=manifest,
        figures=figures,
        repo_root=Path(repo_root),
        manifest_path=_shown_path(
            Path(manifest_path), repo_root=Path(repo_root), report_dir=output.parent
        ),
    )
    provenance.write_markdown(text, output, stamp)
    return text
