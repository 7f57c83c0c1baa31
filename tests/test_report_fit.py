"""The figures' text fits them whatever the task calls things, and an empty panel says why it is
empty. Drawn from synthetic traces (no rollout): fast."""

from __future__ import annotations

import dataclasses
import re

import numpy as np
from matplotlib.figure import Figure
from test_report_statements import TASK, _summary

from mjtrial.report.figures import figure_sample_traces
from mjtrial.report.fit import fit_text, fitted_title
from mjtrial.report.traces import SampleTraces

NOMINAL = {"fast": True, "slow": True}
LONG_TITLE = "frictionloss_doubled_fast_lift (frictionloss_scale 2, lift_time 0.15 s)"


def _words_whole(original: str, drawn: str) -> None:
    """Every run of letters and digits of `original` is on one line of `drawn`."""
    lines = drawn.split("\n")
    for word in re.findall(r"[A-Za-z0-9]+", original):
        assert any(word in line for line in lines), (word, lines)
    assert "".join(drawn.split()) == "".join(original.split())  # nothing lost or added


def test_a_title_too_wide_for_its_panel_breaks_between_words_only():
    fig = Figure(figsize=(7, 3))
    axes = fig.subplots(1, 4)
    fitted_title(axes[1], LONG_TITLE, width=fig.bbox.width / 4 * 0.95)
    title = axes[1].title
    _words_whole(LONG_TITLE, title.get_text())
    assert title.get_text().count("\n") >= 2
    assert title.get_window_extent(fig.canvas.get_renderer()).width <= fig.bbox.width / 4


def test_a_long_name_breaks_after_its_underscores_not_inside_a_word():
    fig = Figure(figsize=(2, 2))
    text = fig.text(0.5, 0.5, "frictionloss_doubled_fast_lift_stock_model")
    fit_text(text, width=0.4 * fig.bbox.width)
    lines = text.get_text().split("\n")
    assert len(lines) > 1 and all(line.endswith("_") for line in lines[:-1])
    _words_whole("frictionloss_doubled_fast_lift_stock_model", text.get_text())


def _traces(recorded: bool, name: str) -> SampleTraces:
    time = np.arange(1, 51) * 0.02
    if not recorded:
        return SampleTraces(
            condition=name,
            time=time,
            values=np.zeros((0, 50)),
            state_ids=(),
            success=(),
            log_interval=0.02,
            marks={},
            unrecorded={"succeeded": (0, 1), "failed": (2,)},
        )
    return SampleTraces(
        condition=name,
        time=time,
        values=np.vstack([np.linspace(0, 0.3, 50), np.linspace(0, 0.01, 50)]),
        state_ids=(0, 2),
        success=(True, False),
        log_interval=0.02,
        marks={},
    )


def _panel_texts(ax) -> list[str]:
    return [t.get_text() for t in ax.texts]


def test_a_panel_without_a_recorded_episode_says_why():
    summary = _summary({"fast": [True, True, False], "slow": [True, True, False]}, NOMINAL)
    traces = {"fast": _traces(True, "fast"), "slow": _traces(False, "slow")}
    fig = figure_sample_traces(traces=traces, summary=summary, task=TASK)
    said = " ".join(" ".join(_panel_texts(ax)).replace("\n", " ") for ax in fig.axes)
    assert "No sample episode of this condition was recorded" in said
    assert "succeeded: states 0, 1; failed: states 2" in said
    assert "recording.episodes" in said
    # the panel with traces says nothing of the kind
    assert not any("No sample episode" in t for t in _panel_texts(fig.axes[0]))


def test_a_long_y_label_stays_on_the_canvas():
    series = dataclasses.replace(
        TASK.trace_series,
        name="height_of_the_grasped_object_above_the_table_top_surface_in_the_world_frame",
    )
    task = dataclasses.replace(TASK, series=(series,), trace=None)
    summary = _summary({"fast": [True, True, False], "slow": [True, True, False]}, NOMINAL)
    traces = {"fast": _traces(True, "fast"), "slow": _traces(True, "slow")}
    fig = figure_sample_traces(traces=traces, summary=summary, task=task)
    fig.draw_without_rendering()
    renderer = fig.canvas.get_renderer()
    label = fig.axes[0].yaxis.label
    box = label.get_window_extent(renderer)
    assert box.y0 >= fig.bbox.y0 - 0.5 and box.y1 <= fig.bbox.y1 + 0.5, label.get_text()
    _words_whole(label.get_text().replace("\n", " "), label.get_text())
    suptitle = fig.get_suptitle()
    assert fig._suptitle.get_window_extent(renderer).width <= fig.bbox.width, suptitle
