"""What the report's figures and studies say is true of what they drew and counted: a traces
caption and title when nothing was recorded."""

from __future__ import annotations

import numpy as np
from gantry_lift.task import TASK

from mjtrial.report.figures import _traces_title
from mjtrial.report.text import _traces_caption
from mjtrial.report.traces import SampleTraces


def _traces(state_ids: tuple[int, ...], interval: float) -> SampleTraces:
    time = np.arange(1, 11) * interval
    return SampleTraces(
        condition="c",
        time=time,
        values=np.zeros((len(state_ids), len(time))),
        state_ids=state_ids,
        success=tuple(False for _ in state_ids),
        log_interval=interval,
        marks={},
        unrecorded={} if state_ids else {"succeeded": (0, 1, 2)},
    )


def _summary(failures: int) -> dict:
    return {
        "conditions": {"a": {"n": 20, "successes": 20 - failures}, "b": {"n": 20, "successes": 20}}
    }


def test_nothing_recorded_is_said_and_no_interval_claimed():
    """robosuite's run: `recording.episodes: failed`, none failed: four empty panels."""
    none_drawn = {"a": _traces((), 0.002), "b": _traces((), 0.002)}
    assert _traces_title("cube_height", none_drawn) == "Cube height: no sample episode was recorded"
    caption = _traces_caption(_summary(0), {"recording": {"episodes": "failed"}}, TASK)
    assert "from their recordings" not in caption
    assert caption.endswith(
        "no sample episode drawn (`recording.episodes: failed` records failed episodes, and "
        "none failed)"
    )
    none = _traces_caption(_summary(3), {"recording": {"episodes": "none"}}, TASK)
    assert "no sample episode drawn (`recording.episodes: none` records no episode)" in none


def test_the_interval_is_that_of_the_episodes_drawn():
    traces = {"a": _traces((4, 7), 0.01), "b": _traces((), 0.002)}
    assert _traces_title("cube_height", traces).endswith("as recorded every 10 ms")
    failed = _traces_caption(_summary(2), {"recording": {"episodes": "failed"}}, TASK)
    assert "in sample failed episodes, from their recordings" in failed
    every = _traces_caption(_summary(2), {"recording": {"episodes": "all"}}, TASK)
    assert every.endswith("over time in sample episodes, from their recordings")


def test_a_degenerate_dose_response_comparison_is_said_in_words():
    """The Sawyer run: every state succeeds at the reference and fails at the longest value
    (-1, a one-point interval), one value equals the reference on every state (0, no
    discordance), and the trend is steep: its odds ratio's lower bound is small, not 0.000."""
    from mjtrial.report.studies import render_dose_response_section
    from mjtrial.studies.dose_response import summarize_dose_response

    n = 20
    outcomes = {
        0.1: np.ones(n, bool),
        0.2: np.ones(n, bool),
        0.4: np.arange(n) < 19,
        0.8: np.arange(n) < 1,
        1.6: np.zeros(n, bool),
    }
    tables = {v: {"state_id": np.arange(n), "success": s} for v, s in outcomes.items()}
    summary = summarize_dose_response(
        tables,
        parameter="latency",
        states={"state_id": np.arange(n), "mass": np.linspace(0.05, 0.6, n)},
        band_parameter="mass",
        band_edges=[0.05, 0.3, 0.6],
        analysis={"confidence": 0.95, "n_resamples": 200, "seed": 3},
        margin=0.05,
        reference=0.1,
        toward="larger",
    )
    text = render_dose_response_section(summary, figure="f.png")
    assert "-1.000 [-1.000, -1.000]" not in text and "[+0.000, +0.000]" not in text
    assert (
        "| 1.6 | 0/20 0.000 [0.000, 0.161] | 0/9 0.000 [0.000, 0.299] | 0/11 0.000 [0.000, 0.259] "
        "| -1.000 (all 20 states failed here and succeeded at the reference; the bootstrap "
        "interval is that one point) |" in text
    )
    assert "| +0.000 (no discordant pair: each of the 20 states had one outcome at both" in text
    low = summary["trend"]["odds_ratio_per_doubling_low"]
    assert 0 < low < 0.0005  # what 0.000 hid
    assert f"odds ratio per doubling 0.00272 [{low:.3g}, 0.045]" in text


def test_the_traces_figure_keeps_its_text_apart_at_five_conditions():
    """The Sawyer run's five conditions: panels in rows of three, each legend below its own
    axis label (one row of five put the legends over the labels)."""
    from test_report import _text_problems

    from mjtrial.report.figures import figure_sample_traces

    names = ["scripted", "scripted_slow", "clone_a", "clone_b", "clone_c"]
    time = np.arange(1, 101) * 0.02
    values = np.vstack([0.15 + 0.15 * np.sin(time * (k + 1)) for k in range(6)])
    traces = {
        n: SampleTraces(
            condition=n,
            time=time,
            values=values,
            state_ids=(0, 1, 2, 3, 5, 8),
            success=(True, True, True, False, False, False),
            log_interval=0.02,
            marks={"lift": 0.5, "hold": 1.2},
        )
        for n in names
    }
    summary = {"conditions": {n: {"n": 20, "successes": 10, "lift_time": 0.15} for n in names}}
    for shown in (names, names[:2]):
        fig = figure_sample_traces(
            traces={n: traces[n] for n in shown},
            summary={"conditions": {n: summary["conditions"][n] for n in shown}},
            task=TASK,
        )
        assert _text_problems(fig) == []
        assert sum(ax.get_visible() for ax in fig.axes) == len(shown)
