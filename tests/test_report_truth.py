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
