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
from mjtrial.analysis import DECISION_EXACT, DECISION_SEQUENTIAL
from mjtrial.report.comparisons import (
    comparisons_section,
    metric_lines,
    paired_text,
    tests_text,
)
from mjtrial.report.labels import (
    band_parameter,
    failure_categories,
    markdown_table,
    pct,
    rate_cell,
    setting,
)
from mjtrial.report.registration import falsifier_clause, registration_lines
from mjtrial.report.setup import setup_section
from mjtrial.report.stopping import stopping_section
from mjtrial.sim.physics import load_model
from mjtrial.stages.stamping import DECLARED_STUDIES, declared_studies
from mjtrial.task import Task, load_task


def _interval(low: float, high: float, *, signed: bool = False) -> str:
    return f"[{low:+.3f}, {high:+.3f}]" if signed else f"[{low:.3f}, {high:.3f}]"


def _traces_caption(summary: Mapping[str, Any], config: Mapping[str, Any], task: Task) -> str:
    """The traces figure's caption, true of what it draws: the lowest-id successes and
    failures that were recorded (`recording.episodes`: all, failed or none)."""
    series = (task.trace_series.name.replace("_", " ") if task.trace_series else "").capitalize()
    kept = config.get("recording", {}).get("episodes", "all")
    failed = sum(c["n"] - c["successes"] for c in summary["conditions"].values())
    if kept == "all":
        return f"{series} over time in sample episodes, from their recordings"
    if kept == "failed" and failed:
        return (
            f"{series} over time in sample failed episodes, from their recordings "
            "(`recording.episodes: failed`: successes are not recorded)"
        )
    why = "records no episode" if kept == "none" else "records failed episodes, and none failed"
    return f"{series}: no sample episode drawn (`recording.episodes: {kept}` {why})"


def _captions(summary: Mapping[str, Any], task: Task) -> dict[str, str]:
    """The result figures' captions (the traces' is `_traces_caption`: it needs the config)."""
    band = next(iter(summary["bands"]), "")
    return {
        "success_by_condition": "Success rate per condition",
        "success_by_band": f"Success rate by {band_parameter(band, task)[0]} band",
        "paired_outcomes": "Paired outcomes of the same initial states",
        "failure_categories": "Failed episodes by category",
    }


_RESULT_FIGURES = ("success_by_condition", "success_by_band", "paired_outcomes")
_FAILURE_FIGURES = ("failure_categories", "sample_traces")

_MISTAKE_WHY = {
    "nominal_state": (
        "One episode per condition: {each}. An interval from one episode covers most of the "
        "possible rates, so the shortcut cannot separate the conditions; and the nominal state is "
        "one point, no sample of the distribution of {parameters} the evaluation draws from."
    ),
    "first_k": (
        "{k} states give intervals {ratio:.1f} times as wide as the {n} states (mean width "
        "{width_k:.3f} against {width_n:.3f}), and the first states are just a smaller sample "
        "of the same seed, not a better one: the rates move by chance alone."
    ),
}


def _scope_limits(config: Mapping[str, Any]) -> tuple[str, ...]:
    """What no experiment of this tool shows, beside the task's own limitations: a study is
    named only as what the config declares, never as a result (it is reported on its own)."""
    study = (
        " The config declares a sensitivity study of solver and contact settings "
        "(`snakemake -c2 sensitivity`, reported on its own in `report_sensitivity.md`); "
        "this report includes none of its results."
        if "sensitivity" in config.get(DECLARED_STUDIES, declared_studies(config))
        else " No sensitivity study is configured for this experiment."
    )
    return (
        "**One simulator version.** Every number comes from the MuJoCo version listed under "
        "Reproduction, with one timestep, integrator and contact model; whether the effect "
        "survives other solver and contact settings is not tested here." + study,
    )


def _load_reported_model(manifest: Mapping[str, Any], repo_root: Path) -> mujoco.MjModel:
    """The model the manifest names, refusing a file whose hash differs from the one that ran."""
    path = Path(repo_root) / manifest["model"]["path"]
    sha = provenance.model_sha256(path)
    if sha != manifest["model"]["sha256"]:
        raise ValueError(
            f"{path}: sha256 {sha} differs from the manifest's {manifest['model']['sha256']}; "
            "the report would describe a model other than the one that ran"
        )
    return load_model(path)


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


def _figure_lines(
    names: Sequence[str], figures: Mapping[str, str], captions: Mapping[str, str]
) -> list[str]:
    lines = []
    for name in names:
        if name in figures:
            svg = str(Path(figures[name]).with_suffix(".svg").as_posix())
            lines += [
                f"![{captions.get(name, name)}]({figures[name]})",
                "",
                f"*{captions.get(name, name)}* ([SVG]({svg})).",
                "",
            ]
    return lines


def _metric(summary: Mapping[str, Any], manifest: Mapping[str, Any]) -> list[str]:
    success = manifest["success_definition"]
    conf = pct(summary["confidence"])
    return [
        "## Metric",
        "",
        f"- Success: {success}.",
        "- Each episode's outcome is binary (1 = success). A condition's success rate is the mean "
        f"over its n = {summary['n_states']} evaluation states (the per-task mean; this "
        "experiment has one task).",
        f"- Success rates carry {conf} Wilson score intervals.",
        *metric_lines(summary),
    ]


def _band_section(
    summary: Mapping[str, Any], parameter: str, names: Sequence[str], task: Task
) -> list[str]:
    label, unit = band_parameter(parameter, task)
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
        *markdown_table([head, "n", *names], rows),
        "",
    ]


def _results(
    summary: Mapping[str, Any], figures: Mapping[str, str], names: Sequence[str], task: Task
) -> list[str]:
    conf = pct(summary["confidence"])
    conditions = summary["conditions"]
    primary = summary["comparisons"][0]
    treatment, baseline = primary["treatment"], primary["baseline"]
    d = primary["table"]
    lines = [
        "## Results",
        "",
        *markdown_table(
            [
                "condition",
                "setting",
                "successes",
                "success rate",
                f"{conf} Wilson interval",
                "unhealthy episodes",
            ],
            [
                [
                    name,
                    setting(rec, task),
                    f"{rec['successes']}/{rec['n']}",
                    f"{rec['rate']:.3f}" if rec["n"] else "-",
                    _interval(rec["wilson_low"], rec["wilson_high"]) if rec["n"] else "-",
                    rec["unhealthy"],
                ]
                for name, rec in conditions.items()
            ],
        ),
        "",
        paired_text(primary),
        "",
        "Paired outcomes (number of initial states):",
        "",
        *markdown_table(
            ["", f"{treatment} succeeds", f"{treatment} fails"],
            [
                [f"**{baseline} succeeds**", d["both"], d[f"only_{baseline}"]],
                [f"**{baseline} fails**", d[f"only_{treatment}"], d["neither"]],
            ],
        ),
        "",
        tests_text(primary, summary["multiple_comparisons"]),
        "",
        *comparisons_section(summary),
    ]
    for parameter in summary["bands"]:
        lines += _band_section(summary, parameter, names, task)
    pooled = summary.get("pooled_over")
    if pooled:
        n = summary["n_states"]
        first = next(iter(summary["bands"]))
        label, unit = band_parameter(first, task)
        dist = ", ".join(
            f"{b['band']}: {b['n']} ({b['n'] / n:.1%})" for b in pooled[f"{first}_bands"]
        )
        lines += [
            f"Pooling caveat: {pooled['what']}. The evaluation's {label} distribution"
            f"{f' ({unit})' if unit else ''}: {dist}. A pooled rate is the per-band rates "
            f"weighted by these shares, so another {label} distribution gives another pooled "
            "rate; the per-band rates are what carries over.",
            "",
        ]
    captions = _captions(summary, task)
    lines += _figure_lines(_RESULT_FIGURES, figures, captions)
    other = [n for n in figures if n not in _RESULT_FIGURES + _FAILURE_FIGURES]
    lines += _figure_lines(other, figures, captions)
    return lines


def _failure_analysis(
    summary: Mapping[str, Any],
    config: Mapping[str, Any],
    figures: Mapping[str, str],
    names: Sequence[str],
    task: Task,
) -> list[str]:
    failures = summary["failures"]
    categories = failure_categories(summary, task.category_names())
    rows = [[c, *(failures[name].get(c, 0) for name in names)] for c in categories]
    rows.append(["**all failures**", *(sum(failures[name].values()) for name in names)])
    thresholds = ", ".join(
        f"{k} {v:g} {task.unit_of(k)}".rstrip()
        for k, v in config.get("failure_taxonomy", {}).items()
    )
    lines = [
        "## Failure analysis",
        "",
        "Each failed episode gets exactly one category, the first that applies in the order "
        "below (the task's failure categories"
        + (f"; thresholds from the config: {thresholds})." if thresholds else ")."),
        "",
        *markdown_table(["category", *names], rows),
        "",
        *(
            f"- {c.name}: {c.description}"
            for c in task.failure_categories
            if c.description != c.name
        ),
        "",
    ]
    return lines + _figure_lines(
        _FAILURE_FIGURES,
        figures,
        {**_captions(summary, task), "sample_traces": _traces_caption(summary, config, task)},
    )


def _falsifier(summary: Mapping[str, Any], manifest: Mapping[str, Any]) -> list[str]:
    f = summary["falsifier"]
    confidence = summary["paired_difference"]["confidence"]
    conf = pct(confidence)
    statistic = f"{f['statistic']} ({f['treatment']} - {f['baseline']})"
    rule = {
        DECISION_SEQUENTIAL: "the hypothesis is refuted unless the stopping rule's one-sided "
        "test (Stopping early, below) rejects no paired difference in its direction at some "
        f"look, the last at the maximum N included; the {conf} interval of {statistic} is "
        "given beside it",
        DECISION_EXACT: "the hypothesis is refuted unless the exact McNemar test rejects no "
        f"paired difference in its direction at one-sided {(1 - confidence) / 2:g} (two-sided "
        f"p at most {1 - confidence:g}, more discordant pairs to {f['treatment']}); the {conf} "
        f"interval of {statistic} is given beside it",
    }.get(
        f.get("decision"),
        f"the hypothesis is refuted when the lower bound of the {conf} interval of {statistic} "
        f"is at or below {f['threshold']:g}",
    )
    return [
        "## Falsifier",
        "",
        f"{falsifier_clause(manifest)}{rule}.",
        "",
        f"Verdict: **{f['verdict'].upper()}**.",
        "",
        f"> {f['reason']}",
    ]


def _mistakes(summary: Mapping[str, Any], names: Sequence[str], task: Task) -> list[str]:
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
    lines += [*markdown_table(["evaluated on", *names], rows), ""]

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
        each = "; ".join(f"{n} {_outcome(mistake['conditions'][n])}" for n in names)
        width_k = float(np.mean([width(r) for r in recs]))
        width_n = float(np.mean([width(r) for r in full]))
        text = why.format(
            each=each,
            k=mistake.get("k", recs[0]["n"]),
            n=summary["n_states"],
            ratio=width_k / width_n if width_n else float("inf"),
            width_k=width_k,
            width_n=width_n,
            parameters=", ".join(p.description or p.name for p in task.state_parameters),
        )
        lines += [f"- *{mistake['what'][0].upper()}{mistake['what'][1:]}*: {text}"]
    return lines


def _outcome(rec: Mapping[str, Any]) -> str:
    """One condition's outcome under a shortcut: `succeeded (1/1, interval [0.207, 1.000])`."""
    if not rec["n"]:
        return "no episode"
    word = (
        ("succeeded" if rec["successes"] else "failed") if rec["n"] == 1 else f"{rec['rate']:.3f}"
    )
    return f"{word} ({rec['successes']}/{rec['n']}, interval " + (
        f"{_interval(rec['wilson_low'], rec['wilson_high'])})"
    )


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
        *markdown_table(["package", "version"], [[k, v] for k, v in manifest["versions"].items()]),
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
    task = load_task(config["task"], repo_root=Path(repo_root))
    names = list(summary["conditions"])
    design = config.get("design", {})
    lines = [f"# {config.get('experiment', manifest.get('experiment', 'Experiment'))}", ""]
    if design.get("question"):
        lines += [f"**Question.** {design['question']}", ""]
    if design.get("hypothesis"):
        lines += [f"**Hypothesis.** {design['hypothesis']}", ""]
    sections = [
        setup_section(summary, config, manifest, model, task, Path(repo_root)),
        _metric(summary, manifest),
        _results(summary, figures, names, task),
        _failure_analysis(summary, config, figures, names, task),
        _falsifier(summary, manifest),
        stopping_section(summary),
        registration_lines(manifest, summary),
        _mistakes(summary, names, task),
        [
            "## What this experiment does not show",
            "",
            *(f"- {s}" for s in (*task.limitations, *_scope_limits(config))),
        ],
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
