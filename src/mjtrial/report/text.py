"""The Markdown report: the experiment as a reader of the paper sees it.

Every number in the report is formatted from `summary.json`, `manifest.json`, the config or the
model the manifest names; none is typed here, so the report cannot drift from the results.
"""

from __future__ import annotations

import json
import os
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import mujoco
import numpy as np

from mjtrial import REPO_ROOT, provenance
from mjtrial.report.labels import UNITS, band_parameter, failure_categories, pct, rate_cell
from mjtrial.states import STATE_PARAMETERS

# Units of the failure taxonomy's thresholds (mjtrial.taxonomy.Thresholds).
_TAXONOMY_UNITS = {
    "lifted_height": "m",
    "slip_distance": "m",
    "workspace_radius": "m",
    "max_tilt": "rad",
}


def _interval(low: float, high: float, *, signed: bool = False) -> str:
    return f"[{low:+.3f}, {high:+.3f}]" if signed else f"[{low:.3f}, {high:.3f}]"


_CAPTIONS = {
    "success_by_condition": "Success rate per condition",
    "success_by_mass": "Success rate by cube mass band",
    "paired_outcomes": "Paired outcomes of the same initial states",
    "failure_categories": "Failed episodes by category",
    "cube_height": "Cube height over time in sample episodes, from their recordings",
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
                [p, f"{states['ranges'][p][0]:g}", f"{states['ranges'][p][1]:g}", UNITS.get(p, "")]
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
            f"a {pct(summary['confidence'])} half-width of {plan['target_halfwidth']:g} at worst"
            f": {met}.",
        ]
    return lines


def _metric(summary: Mapping[str, Any], manifest: Mapping[str, Any]) -> list[str]:
    success = manifest["success_definition"]
    paired = summary["paired_difference"]
    conf = pct(summary["confidence"])
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
        f"success({paired['baseline']}), with a {pct(paired['confidence'])} interval by "
        f"{paired['method']} ({paired['n_resamples']} resamples, seed {paired['seed']}).",
        f"- Discordant pairs: {summary['mcnemar']['method']}.",
    ]


def _band_section(summary: Mapping[str, Any], parameter: str, names: Sequence[str]) -> list[str]:
    label, unit = band_parameter(parameter)
    conditions = summary["conditions"]
    rows = [
        [f"{b['band']}", b["n"], *(rate_cell(b["conditions"][name]) for name in names)]
        for b in summary["bands"][parameter]
    ]
    rows.append(
        ["all (pooled)", summary["n_states"], *(rate_cell(conditions[name]) for name in names)]
    )
    head = f"{label} band ({unit})" if unit else f"{label} band"
    return [
        f"Success by {label} band (k/n, rate, {pct(summary['confidence'])} Wilson interval):",
        "",
        *_table([head, "n", *names], rows),
        "",
    ]


def _results(
    summary: Mapping[str, Any], figures: Mapping[str, str], names: Sequence[str]
) -> list[str]:
    conf = pct(summary["confidence"])
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
        f"{pct(paired['confidence'])} interval "
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
    categories = failure_categories(summary)
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
    conf = pct(summary["paired_difference"]["confidence"])
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
    conf = pct(summary["confidence"])
    conditions = summary["conditions"]
    lines = [
        "## Two classic evaluation mistakes, reproduced",
        "",
        f"Success rate with {conf} Wilson interval under each shortcut, beside the real result:",
        "",
    ]
    rows = [
        [f"{summary['n_states']} evaluation states (the result)"]
        + [rate_cell(conditions[name]) for name in names]
    ]
    for mistake in summary["mistakes"].values():
        rows.append([mistake["what"], *(rate_cell(mistake["conditions"][n]) for n in names)])
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
    """`path` relative to the repository when inside it (as written, or resolved), else to the
    report's folder."""
    return provenance.path_in_repo(path, repo_root) or _relative(path, report_dir)


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
    text = report_text(
        summary_path=summary_path,
        config=config,
        manifest_path=manifest_path,
        figure_paths=figure_paths,
        output=output,
        repo_root=repo_root,
    )
    provenance.write_markdown(text, output, stamp)
    return text


def report_text(
    *,
    summary_path: Path,
    config: Mapping[str, Any],
    manifest_path: Path,
    figure_paths: Sequence[Path],
    output: Path,
    repo_root: Path = REPO_ROOT,
) -> str:
    """The Markdown `write_report` writes to `output` (`mjtrial verify` checks against it)."""
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
    return text
