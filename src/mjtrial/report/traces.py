"""Sample episodes' traces of the task's chosen series (`Task.trace`), read from the rollout
recordings: what a success and a failure look like over time."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pyarrow.parquet as pq

from mjtrial.recording import list_recordings, read_episode
from mjtrial.recording.read import find_episode_file
from mjtrial.sim.engine import episode_steps
from mjtrial.task import BoundTask, call

# Episodes of each outcome per condition drawn in the traces figure.
TRACES_PER_OUTCOME = 3


@dataclass(frozen=True)
class SampleTraces:
    """One series of a few recorded episodes of one condition, at the logged steps.

    Attributes:
      condition: the condition's name.
      time: (n_logged,) time after each logged step on the step clock, s.
      values: (n_episodes, n_logged) the series' values.
      state_ids: (n_episodes,) the episodes' state ids.
      success: (n_episodes,) the episodes' outcomes in the rollout table.
      log_interval: time between logged steps, s (the last step is logged even if closer).
      marks: the task's protocol events on this condition's clock, label -> time (s).
      unrecorded: the state ids of chosen episodes that have no recording (the config's
        `recording.episodes` keeps only some), by outcome: "succeeded" or "failed" -> ids.
    """

    condition: str
    time: np.ndarray
    values: np.ndarray
    state_ids: tuple[int, ...]
    success: tuple[bool, ...]
    log_interval: float
    marks: Mapping[str, float]
    unrecorded: Mapping[str, tuple[int, ...]] = field(default_factory=dict)


def _chosen_episodes(table_path: Path, per_outcome: int) -> list[tuple[int, dict]]:
    """The lowest-id successes and failures, by state id, with their table rows: a choice fixed
    in advance, not a pick of telling examples."""
    table = pq.read_table(table_path)
    columns = {c: table.column(c).to_numpy(zero_copy_only=False) for c in table.column_names}
    order = np.argsort(columns["state_id"], kind="stable")
    success = np.asarray(columns["success"], dtype=bool)[order]
    rows = sorted([*np.flatnonzero(success)[:per_outcome], *np.flatnonzero(~success)[:per_outcome]])
    return [
        (int(columns["state_id"][order[r]]), {c: v[order[r]] for c, v in columns.items()})
        for r in rows
    ]


def record_difference(record: Mapping[str, object], row: Mapping[str, object]) -> str | None:
    """What the recording's episode record says that its table row does not."""
    for key in ("success", *(k for k in record if k in row and k != "state_id")):
        if key not in record or key == "failure_category" and record[key] is None:
            continue
        mine, theirs = record[key], row[key]
        same = mine == theirs or (
            isinstance(mine, float)
            and isinstance(theirs, float)
            and np.isnan(mine)
            and np.isnan(theirs)
        )
        if not same:  # numpy scalars said as numbers and booleans (`np.True_` before)
            mine, theirs = (getattr(v, "item", lambda v=v: v)() for v in (mine, theirs))
            return f"recorded {key} {mine!r} differs from {theirs!r}"
    return None


def sample_traces(
    *,
    bound: BoundTask,
    rollout_tables: Mapping[str, Path],
    recordings: Mapping[str, Sequence[Path]],
    conditions: Mapping[str, Mapping[str, float]],
    per_outcome: int = TRACES_PER_OUTCOME,
    condition_bounds: Mapping[str, BoundTask] | None = None,
) -> dict[str, SampleTraces]:
    """Read up to `per_outcome` successes and failures of each condition from its recordings.

    Args:
      bound: the task on the model that ran; its `trace_series` is read.
      rollout_tables: condition -> its rollout table.
      recordings: condition -> its shards' folders of recordings (the run's own, as the layout
        names them: a folder an earlier run left is never read).
      conditions: condition -> its protocol parameters (config `conditions.<name>`).
      per_outcome: episodes of each outcome per condition.
      condition_bounds: condition -> its task on its own model (`stages.condition.condition_task`),
        where it edits the model or names a policy file: its steps and time axis are its own
        (another timestep, other steps). A condition not in it ran `bound`.

    Raises:
      ValueError: a recording's episode record disagrees with its table row (the figure would
        label a trajectory with an outcome it did not have), its logged steps are not the
        condition's, or the chosen episodes were logged at different steps.
    """
    series = bound.task.trace_series
    traces = {}
    for name, table_path in rollout_tables.items():
        ran = (condition_bounds or {}).get(name, bound)
        task, model = ran.task, ran.model
        timestep = float(model.opt.timestep)
        n_steps = episode_steps(ran, conditions[name])
        params = task.parameters(conditions[name])
        marks = (
            dict(call(task, "trace_marks", task.trace_marks, model, params))
            if task.trace_marks
            else {}
        )
        steps: np.ndarray | None = None
        values, drawn = [], []
        unrecorded: dict[str, tuple[int, ...]] = {}
        for state_id, row in _chosen_episodes(Path(table_path), per_outcome):
            try:
                file = find_episode_file(recordings[name], condition=name, state_id=state_id)
            except KeyError:  # not recorded (recording.episodes: failed or none): not drawn
                outcome = "succeeded" if row["success"] else "failed"
                unrecorded[outcome] = (*unrecorded.get(outcome, ()), state_id)
                continue
            where = f"{file}: {name} state {state_id}"
            record = next(r for r in list_recordings(file) if r.get("state_id") == state_id)
            stale = record_difference(record, row)
            if stale:
                raise ValueError(f"{where}: {stale} in {table_path}; the rollouts are stale")
            logged = read_episode(file, condition=name, state_id=state_id)
            if logged["step"][-1] + 1 != n_steps:
                raise ValueError(
                    f"{where}: {logged['step'][-1] + 1} steps recorded, but the condition's "
                    f"episodes have {n_steps} at timestep {timestep:g} s"
                )
            if steps is None:
                steps = logged["step"]
            elif not np.array_equal(logged["step"], steps):
                raise ValueError(f"{where}: logged at other steps than the condition's others")
            values.append(logged[series.name])
            drawn.append((state_id, bool(row["success"])))
        if steps is None:
            steps = np.arange(n_steps)
        traces[name] = SampleTraces(
            condition=name,
            time=(steps + 1) * timestep,
            values=np.array(values).reshape(len(values), len(steps)),
            state_ids=tuple(s for s, _ in drawn),
            success=tuple(ok for _, ok in drawn),
            log_interval=float((steps[1] - steps[0]) * timestep) if len(steps) > 1 else timestep,
            marks={k: float(v) for k, v in marks.items()},
            unrecorded=unrecorded,
        )
    return traces
