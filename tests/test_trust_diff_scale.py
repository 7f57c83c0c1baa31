"""The fourth hostile survey, `mjtrial diff` at scale: a change that flipped 311 episodes printed
311 lines, 261 of them "not compared", with no summary, and a 67 MB diff.rrd. Each test failed
before its fix."""

from __future__ import annotations

from mjtrial.diff import flips
from mjtrial.diff.gate import render
from mjtrial.diff.source import Run


def _flip(state_id: int, category: str, divergence: dict) -> dict:
    return {
        "state_id": state_id,
        "success": [False, True],
        "failure_category": [category, None],
        "divergence": divergence,
    }


def _diff(flipped: dict) -> dict:
    outputs = {k: [] for k in ("only_a", "only_b", "same", "same_content", "differ")}
    rate = {"n": 400, "successes": 100, "rate": 0.25}
    paired = {"n": 400, "a": rate, "b": rate, "only_a": 0, "only_b": 311, "p_value": 1e-9}
    conditions = {
        g: {"a": rate, "b": rate, "paired": paired, "flipped": f} for g, f in flipped.items()
    }
    return {
        "runs": {"a": "a", "b": "b"},
        "made": {},
        "outputs": {**outputs, "recordings": []},
        "conditions": conditions,
        "effects": {},
        "tolerance": 1e-6,
        "level": 0.05,
        "recording": None,
    }


def test_many_flips_are_summarized_by_condition_and_categories_first():
    parted = {"time": 0.05, "step": [24, 24], "quantity": "cube_z", "difference": 1e-3}
    past = {"reason": "not compared (past the diff recording's size; --max-episodes K)"}
    fast = [_flip(i, "slipped", parted) for i in range(50)]
    fast += [_flip(i, "slipped", past) for i in range(50, 250)]
    fast += [_flip(i, "dropped", past) for i in range(250, 311)]
    text = render(_diff({"fast": fast}))
    lines = text.splitlines()
    start = next(i for i, line in enumerate(lines) if line.startswith("Flipped episodes: 311"))
    summary = lines[start + 1 : start + 3]
    assert summary[0].startswith("  fast: failed (slipped) -> success: 250"), summary
    assert "50 part first at t = 0.05 s" in summary[0], summary
    assert "200 not compared (past the diff recording's size" in summary[0], summary
    assert summary[1].startswith("  fast: failed (dropped) -> success: 61"), summary
    episode_lines = [line for line in lines if line.startswith("  fast state ")]
    assert len(episode_lines) == flips.SHOWN_FLIPS < 20
    assert f"and {311 - flips.SHOWN_FLIPS} more (all in --json)" in text


def test_the_diff_recording_stops_near_its_size_budget(tmp_path, monkeypatch):
    """Both runs' recordings of each flip are copied until they reach about 10 MB."""
    episode = tmp_path / "episode.rrd"
    episode.write_bytes(b"\0" * 1_000_000)  # 1 MB a recording: 2 MB a flip

    def fake_trace(a, b, group, state_id, *, tolerance):
        return {"reason": "the recordings agree"}, (episode, episode)

    monkeypatch.setattr(flips, "_trace", fake_trace)
    conditions = {"fast": {"flipped": [{"state_id": i} for i in range(40)]}}
    run = Run(label="a", root=tmp_path, outputs={})
    traced = flips.trace_flips(run, run, conditions)
    assert len(traced) == flips.DEFAULT_RECORDING_BYTES // 2_000_000 == 5
    last = conditions["fast"]["flipped"][-1]["divergence"]["reason"]
    assert last.startswith("not compared (past the diff recording's"), last
    # --max-episodes still asks for a number of them, whatever their size.
    conditions = {"fast": {"flipped": [{"state_id": i} for i in range(40)]}}
    assert len(flips.trace_flips(run, run, conditions, max_episodes=12)) == 12
