"""A long rollout says how far it is: episodes done of total, rate and time left."""

from __future__ import annotations

import logging
import re

from mjtrial.stages.rollout import Progress


def test_progress_logs_done_rate_and_time_left(caplog, monkeypatch):
    clock = iter([0.0, 5.0, 12.0, 20.0, 25.0])
    monkeypatch.setattr("mjtrial.stages.rollout.time.monotonic", lambda: next(clock))
    progress = Progress("rollout fast", total=400, every=10.0)
    with caplog.at_level(logging.INFO, logger="mjtrial"):
        progress.advance(100)  # t = 5 s: too soon for a line
        progress.advance(100)  # t = 12 s: 200 done at 200/12 episodes/s, 12 s left
        progress.advance(100)  # t = 20 s: 8 s since the last line, none
        progress.advance(100)  # t = 25 s: the end always logs
    lines = [r.getMessage() for r in caplog.records]
    assert lines == [
        "rollout fast: 200/400 episodes, 16.7 episodes/s, 12 s left",
        "rollout fast: 400/400 episodes, 16.0 episodes/s, 0 s left",
    ]
    assert all(re.match(r"rollout fast: \d+/400 episodes", line) for line in lines)
