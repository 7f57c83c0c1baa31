"""Figures and report of a small real experiment (12 states), built with the package's stages."""

from __future__ import annotations

import copy
import json
import re
import shutil
import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np
import pyarrow.compute as pc
import pyarrow.parquet as pq
import pytest
import yaml
from gantry_lift.protocol import PROTOCOL

from mjtrial import provenance, report
from mjtrial.files.layout import FIGURES, RESULTS_DIR, Layout, shard_ids, shard_range
from mjtrial.recording import read_episode
from mjtrial.report.figures import CONDITION_PALETTE, condition_colors
from mjtrial.report.text import render_report
from mjtrial.report.traces import TRACES_PER_OUTCOME, sample_traces
from mjtrial.sim.physics import load_model
from mjtrial.stages.analysis import run_analysis
from mjtrial.stages.manifest import write_manifest
from mjtrial.stages.rollout import gather_condition, run_shard
from mjtrial.stages.stamping import config_slice
from mjtrial.stages.states import build_states
from mjtrial.task import BoundTask, load_task

REPO_ROOT = Path(__file__).resolve().parents[1]
PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"


@pytest.fixture(scope="module")
def experiment(tmp_path_factory) -> dict:
    """States, rollouts (tables and recordings, in shards of 5 states), summary and manifest of a
    12-state copy of the experiment, and its figures and report; the folder is not a git
    repository."""
    root = tmp_path_factory.mktemp("report_experiment")
    shutil.copytree(REPO_ROOT / "models", root / "models")
    shutil.copytree(REPO_ROOT / "tasks", root / "tasks")
    config = yaml.safe_load((REPO_ROOT / "config" / "config.yaml").read_text())
    config["states"]["n"] = 12
    config["rollout"]["shard_size"] = 5
    config["analysis"]["n_resamples"] = 300
    layout = Layout.of(config["experiment"], base=root / RESULTS_DIR)
    model_file = root / config["model"]
    states_path = layout.states
    build_states(states_slice=config_slice("states", config), output=states_path, repo_root=root)
    n, shard_size = config["states"]["n"], config["rollout"]["shard_size"]
    tables, nominals, recordings = {}, {}, {}
    for name in config["conditions"]:
        condition_slice = config_slice("rollout", config, condition=name)
        shards = shard_ids(n, shard_size)
        for shard in shards:
            first, stop = shard_range(shard, shard_size, n)
            run_shard(
                condition_slice=condition_slice,
                states_path=states_path,
                model_file=model_file,
                first=first,
                stop=stop,
                output_table=layout.shard_table(name, shard),
                output_recording=layout.shard_recordings(name, shard),
                nthread=1,
                rule=f"rollout:{name}#{shard}",
                repo_root=root,
            )
        tables[name] = layout.rollout_table(name)
        nominals[name] = layout.nominal_episode(name)
        recordings[name] = layout.recordings(name)
        gather_condition(
            condition_slice=condition_slice,
            shard_tables=[layout.shard_table(name, s) for s in shards],
            model_file=model_file,
            output_table=tables[name],
            output_nominal=nominals[name],
            rule=f"gather:{name}",
            repo_root=root,
        )
    summary_path = layout.summary
    summary = run_analysis(
        states_path=states_path,
        rollout_tables=tables,
        nominal_files=nominals,
        analysis_slice=config_slice("analysis", config),
        output=summary_path,
        repo_root=root,
    )
    manifest_path = layout.manifest
    write_manifest(
        config=config,
        summary_path=summary_path,
        outputs=[states_path, *tables.values(), *nominals.values()],
        model_file=model_file,
        output=manifest_path,
        repo_root=root,
    )
    stamp = provenance.make_stamp(
        rule="report",
        config_slice=config_slice("analysis", config),
        inputs={"summary": summary_path, "manifest": manifest_path},
        repo_dir=root,
    )
    manifest = json.loads(manifest_path.read_text())
    bound = BoundTask.of(load_task(config["task"], repo_root=root), load_model(model_file))
    figure_args = dict(
        summary=summary,
        bound=bound,
        rollout_tables=tables,
        recordings=recordings,
        conditions=config["conditions"],
        stamp=stamp,
    )
    figures = report.write_figures(**figure_args, out_dir=layout.figures_dir)
    output = layout.report
    text = report.write_report(
        summary_path=summary_path,
        config=config,
        manifest_path=manifest_path,
        figure_paths=figures,
        output=output,
        stamp=stamp,
        repo_root=root,
    )
    return {
        "root": root,
        "config": config,
        "summary": summary,
        "manifest": manifest,
        "stamp": stamp,
        "figures": figures,
        "figure_args": figure_args,
        "report": output,
        "text": text,
        "tables": tables,
        "recordings": recordings,
    }


def test_every_figure_is_a_stamped_png_and_svg(experiment):
    figures = experiment["figures"]
    assert [p.name for p in figures] == [
        f"{name}.{ext}" for name in FIGURES for ext in ("png", "svg")
    ]
    for path in figures:
        assert path.is_file(), path
        if path.suffix == ".png":
            assert path.read_bytes().startswith(PNG_SIGNATURE)
        else:
            root = ET.parse(path).getroot()
            assert root.tag == "{http://www.w3.org/2000/svg}svg"
        assert provenance.read_stamp(path) == experiment["stamp"]


def test_figures_are_deterministic(experiment, tmp_path):
    again = report.write_figures(**experiment["figure_args"], out_dir=tmp_path)
    for first, second in zip(experiment["figures"], again, strict=True):
        assert first.name == second.name
        assert first.read_bytes() == second.read_bytes(), first.name


def test_report_is_stamped_and_has_every_section(experiment):
    text = experiment["report"].read_text()
    assert provenance.read_stamp(experiment["report"]) == experiment["stamp"]
    assert text.endswith(experiment["text"])
    for heading in (
        "## Setup",
        "## Metric",
        "## Results",
        "## Failure analysis",
        "## Falsifier",
        "## Two classic evaluation mistakes, reproduced",
        "## What this experiment does not show",
        "## Reproduction",
    ):
        assert f"\n{heading}\n" in text, heading


def test_report_quotes_the_summary(experiment):
    text, summary = experiment["text"], experiment["summary"]
    for rec in summary["conditions"].values():
        assert f"{rec['successes']}/{rec['n']}" in text
    paired = summary["paired_difference"]
    assert f"**{paired['estimate']:+.3f}**" in text
    assert f"[{paired['low']:+.3f}, {paired['high']:+.3f}]" in text
    assert f"({paired['method']})" in text  # Newcombe's
    bootstrap = paired["replaces"]  # kept beside it, named in the Metric section
    assert f"{bootstrap['n_resamples']} resamples, seed {bootstrap['seed']}" in text
    falsifier = summary["falsifier"]
    assert f"Verdict: **{falsifier['verdict'].upper()}**" in text
    assert f"> {falsifier['reason']}" in text
    assert f"p = {summary['mcnemar']['p_value']:.3g}" in text
    for mistake in summary["mistakes"].values():
        assert mistake["what"] in text
    manifest = experiment["manifest"]
    assert manifest["model"]["sha256"] in text
    assert f"MuJoCo {manifest['versions']['mujoco']}" in text
    # The copy is not a git repository, and the report says so.
    assert "not a git repository" in text
    # 12 states do not meet the design's plan.
    assert "**not met**" in text


def _table_after(text: str, marker: str) -> list[list[str]]:
    """Rows (cells) of the first Markdown table after the line starting with `marker`."""
    lines = text.splitlines()
    start = next(i for i, line in enumerate(lines) if line.startswith(marker))
    rows, i = [], start
    while not lines[i].startswith("|"):
        i += 1
    while i < len(lines) and lines[i].startswith("|"):
        cells = [c.strip().replace("\\|", "|") for c in re.split(r"(?<!\\)\|", lines[i])[1:-1]]
        rows.append(cells)
        i += 1
    return rows[2:]  # header and separator


def _cell(rec: dict) -> str:
    return (
        f"{rec['successes']}/{rec['n']} {rec['rate']:.3f} "
        f"[{rec['wilson_low']:.3f}, {rec['wilson_high']:.3f}]"
    )


def test_results_tables_hold_exactly_the_summary_numbers(experiment):
    text, summary = experiment["text"], experiment["summary"]
    rows = _table_after(text, "## Results")
    assert [r[0] for r in rows] == list(summary["conditions"])
    for name, setting, successes, rate, interval, unhealthy in rows:
        rec = summary["conditions"][name]
        assert setting == f"lift_time {rec['lift_time']:g} s"
        assert successes == f"{rec['successes']}/{rec['n']}"
        assert float(rate) == pytest.approx(rec["rate"], abs=5e-4)
        low, high = (float(x) for x in interval.strip("[]").split(","))
        assert low == pytest.approx(rec["wilson_low"], abs=5e-4)
        assert high == pytest.approx(rec["wilson_high"], abs=5e-4)
        assert int(unhealthy) == rec["unhealthy"]

    paired = _table_after(text, "Paired outcomes")
    d, p = summary["discordant"], summary["paired_difference"]
    assert [r[1:] for r in paired] == [
        [str(d["both"]), str(d[f"only_{p['baseline']}"])],
        [str(d[f"only_{p['treatment']}"]), str(d["neither"])],
    ]

    names = list(summary["conditions"])
    for parameter, bands in summary["bands"].items():
        label = f"|{parameter[4:]}|" if parameter.startswith("abs_") else parameter
        rows = _table_after(text, f"Success by {label} band")
        assert len(rows) == len(bands) + 1
        for row, band in zip(rows, bands, strict=False):
            assert row == [
                band["band"],
                str(band["n"]),
                *(_cell(band["conditions"][n]) for n in names),
            ]
        assert rows[-1][1:] == [
            str(summary["n_states"]),
            *(_cell(summary["conditions"][n]) for n in names),
        ]

    failures = _table_after(text, "## Failure analysis")
    for row in failures[:-1]:
        assert row[1:] == [str(summary["failures"][n][row[0]]) for n in names]
    assert len(failures) - 1 == len(summary["failures"][names[0]])


def test_figure_links_point_to_files(experiment):
    text, folder = experiment["text"], experiment["report"].parent
    links = re.findall(r"\]\(([^)]+)\)", text)
    embedded = re.findall(r"!\[[^\]]*\]\(([^)]+)\)", text)
    assert sorted(Path(link).stem for link in embedded) == sorted(FIGURES)
    for link in links:
        assert not Path(link).is_absolute()
        assert (folder / link).is_file(), link


def test_sample_traces_are_the_lowest_ids_recordings_on_the_protocol_clock(experiment):
    args = experiment["figure_args"]
    conditions = experiment["config"]["conditions"]
    lift_times = {name: c["lift_time"] for name, c in conditions.items()}
    traces = sample_traces(
        bound=args["bound"],
        rollout_tables=args["rollout_tables"],
        recordings=args["recordings"],
        conditions=conditions,
    )
    p = PROTOCOL
    close_start = p.settle_time + p.descend_segments * p.segment_time + p.pre_close_time
    rate_hz = experiment["config"]["recording"]["rate_hz"]
    for name, path in experiment["tables"].items():
        table = pq.read_table(path).to_pydict()
        outcome = dict(zip(table["state_id"], table["success"], strict=True))
        t = traces[name]
        wins = sorted(i for i, ok in outcome.items() if ok)[:TRACES_PER_OUTCOME]
        losses = sorted(i for i, ok in outcome.items() if not ok)[:TRACES_PER_OUTCOME]
        assert t.state_ids == tuple(sorted(wins + losses))
        assert t.success == tuple(outcome[i] for i in t.state_ids)
        # Phase boundaries and the episode's end from the protocol's durations (the built-in
        # durations are whole multiples of the timestep).
        lift_time = lift_times[name]
        assert t.marks["close"] == pytest.approx(close_start)
        assert t.marks["lift"] == pytest.approx(close_start + p.close_time)
        assert t.marks["lift end"] == pytest.approx(close_start + p.close_time + lift_time)
        assert t.time[-1] == pytest.approx(t.marks["lift end"] + p.hold_time)
        assert t.log_interval == pytest.approx(1 / rate_hz)
        assert np.diff(t.time)[:-1] == pytest.approx(np.full(t.time.size - 2, 1 / rate_hz))
        for row, state_id in enumerate(t.state_ids):
            logged = read_episode(args["recordings"][name], condition=name, state_id=state_id)
            assert t.time == pytest.approx(logged["time"])  # healthy episodes: same clock
            assert np.array_equal(t.values[row], logged["cube_height"])
            ended_above = t.values[row, -1] > p.success_height
            assert ended_above == outcome[state_id]


def test_sample_traces_refuse_a_table_the_recordings_disagree_with(experiment, tmp_path):
    args = experiment["figure_args"]
    name, path = next(iter(experiment["tables"].items()))
    table = pq.read_table(path)
    column = table.schema.get_field_index("final_height")
    stale = tmp_path / "stale.parquet"
    moved = pc.add(table.column(column), 0.01)
    pq.write_table(table.set_column(column, "final_height", moved), stale)
    with pytest.raises(ValueError, match="recorded final_height .* differs .* stale"):
        sample_traces(
            bound=args["bound"],
            rollout_tables={name: stale},
            recordings=args["recordings"],
            conditions={name: experiment["config"]["conditions"][name]},
            per_outcome=1,
        )
    with pytest.raises(ValueError, match="steps recorded"):
        sample_traces(
            bound=args["bound"],
            rollout_tables={name: path},
            recordings=args["recordings"],
            conditions={name: {"lift_time": 2 * args["conditions"][name]["lift_time"]}},
            per_outcome=1,
        )


def test_render_report_refuses_a_model_that_changed(experiment):
    manifest = copy.deepcopy(experiment["manifest"])
    manifest["model"]["sha256"] = "0" * 64
    with pytest.raises(ValueError, match="sha256"):
        render_report(
            summary=experiment["summary"],
            config=experiment["config"],
            manifest=manifest,
            figures={},
            repo_root=experiment["root"],
        )


def test_condition_colours_are_okabe_ito_and_stable():
    okabe_ito = {"#E69F00", "#56B4E9", "#009E73", "#F0E442", "#0072B2", "#D55E00", "#CC79A7"}
    okabe_ito.add("#000000")
    colours = condition_colors(["fast", "slow", "medium"])
    assert colours == condition_colors(["fast", "slow", "medium"])
    assert len(set(colours.values())) == 3
    assert set(CONDITION_PALETTE) <= okabe_ito
    assert "#F0E442" not in CONDITION_PALETTE  # yellow vanishes on white


# --------------------------------------------------------------------------------------------
# Figure text: no two texts overlap, none leaves the canvas, whatever the conditions are named
# --------------------------------------------------------------------------------------------


def _drawn_texts(fig) -> list[tuple[str, object]]:
    """Every text the figure really draws (a tick outside the view is not), with its box in
    pixels, drawn at the saved resolution under the saved style."""
    import matplotlib
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.text import Text

    from mjtrial.report.figures import _STYLE, FIGURE_DPI

    drawn, original = [], Text.draw

    def draw(text, renderer):
        original(text, renderer)
        if text.get_visible() and text.get_text().strip():
            drawn.append((text.get_text(), text.get_window_extent(renderer)))

    with matplotlib.rc_context(_STYLE):
        fig.set_dpi(FIGURE_DPI)
        Text.draw = draw
        try:
            FigureCanvasAgg(fig).draw()
        finally:
            Text.draw = original
    return drawn


def _text_problems(fig) -> list[str]:
    boxes = _drawn_texts(fig)
    canvas = fig.bbox
    problems = [
        f"outside the canvas: {text!r}"
        for text, box in boxes
        if box.x0 < canvas.x0 - 0.5
        or box.y0 < canvas.y0 - 0.5
        or box.x1 > canvas.x1 + 0.5
        or box.y1 > canvas.y1 + 0.5
    ]
    for i, (text, box) in enumerate(boxes):
        for other, other_box in boxes[i + 1 :]:
            if box.overlaps(other_box):
                problems.append(f"{text!r} overlaps {other!r}")
    return problems


LONG_NAMES = {"fast": "frictionloss_doubled_fast_lift", "slow": "stock_model_slow_lift"}


def _renamed(value, names):
    text = json.dumps(value)
    for old, new in names.items():
        text = text.replace(f'"{old}"', f'"{new}"').replace(f'"only_{old}"', f'"only_{new}"')
    return json.loads(text)


@pytest.mark.parametrize("names", [{}, LONG_NAMES], ids=["as built", "long condition names"])
def test_no_figure_text_overlaps_or_leaves_the_canvas(experiment, names, monkeypatch, tmp_path):
    import mjtrial.report.figures as figures

    drawn = {}
    monkeypatch.setattr(figures, "_save", lambda fig, *, name, **_: [drawn.setdefault(name, fig)])
    args = dict(experiment["figure_args"])
    for key in ("rollout_tables", "recordings", "conditions"):
        args[key] = {names.get(c, c): v for c, v in args[key].items()}
    args["summary"] = _renamed(args["summary"], names)
    figures.write_figures(**args, out_dir=tmp_path)
    assert sorted(drawn) == sorted(FIGURES)
    problems = {name: _text_problems(fig) for name, fig in drawn.items()}
    assert problems == {name: [] for name in FIGURES}


def _dose_response(shortest_index: int) -> dict:
    values = [0.0, 0.005, 0.01, 0.02, 0.04]
    rec = {"rate": 0.6, "wilson_low": 0.5, "wilson_high": 0.7, "n": 100}
    bands = [{**rec, "low": 0.05, "high": 0.2}, {**rec, "low": 0.2, "high": 0.3}]
    return {
        "parameter": "latency",
        "per_value": [{"latency": v, **rec, "bands": bands} for v in values],
        "n_states": 100,
        "band_unit": "kg",
        "band_parameter": "pole_mass",
        "furthest_within_margin": values[shortest_index],
        "toward": "larger",
        "scale": "linear",
        "unit": "s",
        "margin": 0.05,
        "reference": 0.0,
        "confidence": 0.95,
    }


@pytest.mark.parametrize("shortest_index", [0, 2, 4])
def test_the_dose_response_annotation_stays_clear_of_other_text(shortest_index):
    from mjtrial.report.studies import figure_dose_response

    fig = figure_dose_response(dose_response=_dose_response(shortest_index))
    assert _text_problems(fig) == []


def test_the_manifest_records_each_state_parameters_distribution(experiment):
    ranges = experiment["config"]["states"]["ranges"]
    assert experiment["manifest"]["state_distributions"] == {
        name: {"kind": "uniform", "low": low, "high": high} for name, (low, high) in ranges.items()
    }
