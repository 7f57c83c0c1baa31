"""Cube-height traces of the report's sample episodes, read from the rollout recordings."""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pyarrow.parquet as pq

from mjtrial.protocol import Phase, condition_protocol, control_sequence
from mjtrial.recording import read_episode

# Episodes of each outcome per condition drawn in the cube-height figure.
TRACES_PER_OUTCOME = 3


@dataclass(frozen=True)
class HeightTraces:
    """Cube height of a few recorded episodes of one condition, at the logged steps.

    Attributes:
      condition: the condition's name.
      lift_time: its lift duration, s.
      time: (n_logged,) simulated time after each logged step, s.
      height: (n_episodes, n_logged) cube centre height, m.
      state_ids: (n_episodes,) the episodes' state ids.
      success: (n_episodes,) the episodes' outcomes in the rollout table.
      log_interval: time between logged steps, s (the last step is logged even if closer).
      close_start, lift_start, lift_end: phase boundaries, s.
    """

    condition: str
    lift_time: float
    time: np.ndarray
    height: np.ndarray
    state_ids: tuple[int, ...]
    success: tuple[bool, ...]
    log_interval: float
    close_start: float
    lift_start: float
    lift_end: float


@dataclass(frozen=True)
class _Episode:
    state_id: int
    success: bool
    final_height: float


def _chosen_episodes(table_path: Path, per_outcome: int) -> list[_Episode]:
    """The lowest-id successes and failures, by state id: a choice fixed in advance, not a
    pick of telling examples."""
    table = pq.read_table(table_path, columns=["state_id", "success", "final_height"])
    ids = np.asarray(table.column("state_id").to_numpy(), dtype=np.int64)
    success = np.asarray(table.column("success").to_numpy(), dtype=bool)
    final = np.asarray(table.column("final_height").to_numpy(), dtype=np.float64)
    order = np.argsort(ids, kind="stable")
    ids, success, final = ids[order], success[order], final[order]
    rows = [*np.flatnonzero(success)[:per_outcome], *np.flatnonzero(~success)[:per_outcome]]
    return [_Episode(int(ids[r]), bool(success[r]), float(final[r])) for r in sorted(rows)]


def cube_height_traces(
    *,
    rollout_tables: Mapping[str, Path],
    recordings: Mapping[str, Path],
    conditions: Mapping[str, Mapping[str, float]],
    timestep: float,
    per_outcome: int = TRACES_PER_OUTCOME,
) -> dict[str, HeightTraces]:
    """Read up to `per_outcome` successes and failures of each condition from its recordings.

    Args:
      rollout_tables: condition -> its rollout table (`state_id`, `success`, `final_height`).
      recordings: condition -> its folder of recordings, one .rrd per episode.
      conditions: condition -> its protocol parameters (config `conditions.<name>`).
      timestep: the model's timestep, s; the time axis is the step clock, not the logged
        physics time, which stops advancing when a MuJoCo warning halts an episode.
      per_outcome: episodes of each outcome per condition.

    Raises:
      ValueError: a recording disagrees with its table's final height (the figure would label
        a trajectory with an outcome it did not have), its logged steps are not the
        protocol's for this lift time and timestep, or the chosen episodes were logged at
        different steps.
    """
    traces = {}
    for name, table_path in rollout_tables.items():
        lift_time = float(conditions[name]["lift_time"])
        _, phase = control_sequence(
            lift_time, timestep=timestep, protocol=condition_protocol(conditions[name])
        )
        chosen = _chosen_episodes(Path(table_path), per_outcome)
        steps: np.ndarray | None = None
        heights = []
        drawn = []
        for episode in chosen:
            try:
                logged = read_episode(recordings[name], condition=name, state_id=episode.state_id)
            except KeyError:
                continue  # not recorded (recording.episodes: failed or none): not drawn
            drawn.append(episode)
            where = f"{recordings[name]}: {name} state {episode.state_id}"
            if logged["step"][-1] + 1 != len(phase):
                raise ValueError(
                    f"{where}: {logged['step'][-1] + 1} steps recorded, but a {lift_time:g} s "
                    f"lift at timestep {timestep:g} s has {len(phase)}"
                )
            if logged["cube_height"][-1] != episode.final_height:
                raise ValueError(
                    f"{where}: recorded final cube height {logged['cube_height'][-1]!r} differs "
                    f"from {episode.final_height!r} in {table_path}; the rollouts are stale"
                )
            if steps is None:
                steps = logged["step"]
            elif not np.array_equal(logged["step"], steps):
                raise ValueError(f"{where}: logged at other steps than the condition's others")
            heights.append(logged["cube_height"])
        if steps is None:
            steps = np.arange(len(phase))
        lift = np.flatnonzero(phase == Phase.LIFT)
        traces[name] = HeightTraces(
            condition=name,
            lift_time=lift_time,
            time=(steps + 1) * timestep,
            height=np.array(heights).reshape(len(heights), len(steps)),
            state_ids=tuple(e.state_id for e in drawn),
            success=tuple(e.success for e in drawn),
            log_interval=float((steps[1] - steps[0]) * timestep) if len(steps) > 1 else timestep,
            close_start=float(np.flatnonzero(phase == Phase.CLOSE)[0] * timestep),
            lift_start=float(lift[0] * timestep),
            lift_end=float((lift[-1] + 1) * timestep),
        )
    return traces
