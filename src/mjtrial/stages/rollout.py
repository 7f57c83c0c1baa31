"""The rollout stage: every state under one condition, its outcomes, failures and recordings."""

from __future__ import annotations

import copy
import logging
import time
from collections.abc import Callable, Iterator, Mapping, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

import mujoco
import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq

from mjtrial import REPO_ROOT, provenance
from mjtrial.design.conditions import policy_path
from mjtrial.files import atomic
from mjtrial.sim import engine, phases
from mjtrial.sim.physics import drop_asset_cache
from mjtrial.stages.condition import condition_parameters, condition_task, thresholds_of
from mjtrial.stages.stamping import make_stage_stamp, model_inputs, task_inputs
from mjtrial.task import BoundTask, Measure, Task, address

if TYPE_CHECKING:
    from mjtrial import recording
    from mjtrial.recording.write import RecordingSpec

log = logging.getLogger("mjtrial")

EPISODES_RECORDED = ("all", "failed", "none")  # config recording.episodes
# The types of the engine's columns (`mjtrial.task.ENGINE_MEASURES`); a task's are float64.
_ENGINE_TYPES = {
    "steps_simulated": pa.int64(),
    "nonfinite": pa.bool_(),
    "warning": pa.string(),
    "failure_category": pa.string(),
}


def rollout_schema(task: Task) -> pa.Schema:
    """The rollout table's columns and types, fixed: a shard whose every episode succeeded has
    no category to infer a type from, and every shard's table must concatenate into the
    condition's. state_id, success, then the task's measures with the engine's columns."""
    return pa.schema(
        [
            ("state_id", pa.int64()),
            ("success", pa.bool_()),
            *((m.name, _ENGINE_TYPES.get(m.name, pa.float64())) for m in task.table_measures),
        ]
    )


def rollout_columns(task: Task) -> tuple[str, ...]:
    """The rollout table's column names, in order."""
    return tuple(rollout_schema(task).names)


class Progress:
    """How far a long job is: episodes done of total, episodes per second and time left, in
    the log every `every` seconds (and at the end), so a user watching a run knows when it
    will end."""

    def __init__(self, what: str, *, total: int, every: float = 10.0) -> None:
        self.what, self.total, self.every = what, total, every
        self.done = 0
        self.start = self.last = time.monotonic()

    def advance(self, n: int) -> None:
        self.done += n
        now = time.monotonic()
        if now - self.last < self.every and self.done < self.total:
            return
        self.last = now
        rate = self.done / max(now - self.start, 1e-9)
        left = (self.total - self.done) / rate if rate > 0 else float("inf")
        log.info(
            "%s: %d/%d episodes, %.1f episodes/s, %.0f s left",
            self.what,
            self.done,
            self.total,
            rate,
            left,
        )


def read_state_values(
    path: Path, task: Task, *, first: int = 0, stop: int | None = None
) -> dict[str, np.ndarray]:
    """The states with ids in [first, stop) of `states.parquet`: state_id and the task's state
    parameters, checked (every column present, every value finite, the ids in order)."""
    # one file: `ParquetFile`, not `read_table`, whose dataset module imports pandas (~0.3 s
    # of a rollout job's CPU, which nothing here uses)
    table = pq.ParquetFile(path).read()
    missing = [c for c in task.state_columns if c not in table.column_names]
    if missing:
        raise ValueError(
            f"{path}: missing column(s) {missing}; expected {list(task.state_columns)}"
        )
    ids = table.column("state_id").to_numpy()
    stop = len(ids) if stop is None else stop
    rows = np.flatnonzero((ids >= first) & (ids < stop))
    if len(rows) != stop - first or not np.array_equal(ids[rows], np.arange(first, stop)):
        raise ValueError(f"{path}: expected states {first}..{stop - 1}, found {len(rows)}")
    values = {"state_id": ids[rows].astype(np.int64)}
    for p in task.state_parameters:
        column = table.column(p.name).to_numpy()[rows].astype(np.float64)
        bad = ~np.isfinite(column)
        if bad.any():
            raise ValueError(
                f"{path}: column {p.name!r} has non-finite values (first at state "
                f"{int(values['state_id'][np.argmax(bad)])})"
            )
        values[p.name] = column
    return values


def condition_policy_inputs(
    condition_slice: Mapping[str, Any], *, repo_root: Path = REPO_ROOT
) -> dict[str, Any]:
    """A stamp's record of the condition's policy file (graph and contract), or {}."""
    policy = policy_path(condition_slice)
    if not policy:
        return {}
    from mjtrial.policy_files.file import policy_inputs  # a policy's job only (onnx, jsonschema)

    return policy_inputs([Path(repo_root) / policy])


def policy_settings(condition_slice: Mapping[str, Any]) -> dict[str, Any] | None:
    """What a stamp records of how the condition's policy file ran (onnxruntime's version and
    session settings), or None for the task's own policy."""
    if not policy_path(condition_slice):
        return None
    from mjtrial.policy_files.file import runtime_settings  # a policy's job only

    return {"policy_runtime": runtime_settings()}


def condition_batches(
    bound: BoundTask,
    condition_slice: Mapping[str, Any],
    values: Mapping[str, np.ndarray],
    *,
    nthread: int,
    batch_size: int | None = None,
) -> Iterator[engine.Batch]:
    """The condition's episodes of the states `values`, in batches, with their outcomes."""
    return engine.iter_batches(
        bound,
        values,
        condition_parameters(bound, condition_slice),
        thresholds=thresholds_of(bound, condition_slice),
        nthread=nthread,
        batch_size=batch_size,
    )


def log_every(rate_hz: float, timestep: float) -> int:
    """Physics steps between logged steps for a logging rate (at least every step)."""
    return max(1, round(1.0 / (rate_hz * timestep)))


def recorded_measures(task: Task) -> tuple[Measure, ...]:
    return tuple(m for m in task.own_measures if m.recorded)


def recording_spec(bound: BoundTask, n_steps: int, rate_hz: float) -> RecordingSpec:
    """What every recording of the task's episodes shares."""
    # rerun only where a job records (an evaluation job without it: 0.72 s of CPU to import, not
    # 1.41 s): evaluations and trainings never record
    from mjtrial.recording.series import Signal
    from mjtrial.recording.write import RecordingSpec

    task, model = bound.task, bound.model
    return RecordingSpec(
        model=model,
        signals=[
            Signal(s.name, address.resolve(model, "body", s.body), s.plot, read)
            for s, read in zip(task.series, bound.series, strict=True)
        ],
        state_names=[p.name for p in task.state_parameters],
        measure_names=[m.name for m in recorded_measures(task)],
        n_steps=n_steps,
        log_every=log_every(rate_hz, model.opt.timestep),
        episode_model=episode_model(bound),
        moves_mocap=bound.actuation is not None and bound.actuation.moves_mocap,
    )


def episode_model(bound: BoundTask) -> Callable[[Mapping[str, float]], mujoco.MjModel] | None:
    """The function from an episode's state values to its own model, for a task whose state
    parameters or `episode_setup` edit the model (what its recording draws); None when none do."""
    task = bound.task
    if task.episode_setup is None and not any(
        p.apply.stage == "model" for p in task.state_parameters
    ):
        return None
    scratch = mujoco.MjData(bound.model)
    slot = copy.copy(bound.model) if bound.reuses_models else None
    return lambda values: bound.episode(values, scratch=scratch, model=slot)[0]


def episode_records(task: Task, batch: engine.Batch) -> Iterator[recording.EpisodeRecord]:
    """The batch's episodes as `recording.EpisodeRecord`s, with their outcomes."""
    from mjtrial import recording  # rerun where a job records only (`recording_spec`)

    names = [p.name for p in task.state_parameters]
    measures = [m.name for m in recorded_measures(task)]
    out = batch.outcome
    for i in range(len(out["success"])):
        yield recording.EpisodeRecord(
            state_id=int(batch.values["state_id"][i]),
            values={n: float(batch.values[n][i]) for n in names},
            physics=batch.episodes.physics[i],
            sensordata=batch.episodes.sensordata[i],
            ctrl=batch.episodes.ctrl[i],
            success=bool(out["success"][i]),
            measures={m: float(out[m][i]) for m in measures},
            failure_category=out["failure_category"][i],
            mocap=None if batch.episodes.mocap is None else batch.episodes.mocap[i],
        )


def outcome_table(task: Task, columns: Mapping[str, Sequence[np.ndarray]]) -> pa.Table:
    """The rollout table from its columns' batches."""
    schema = rollout_schema(task)
    merged = {
        c: np.concatenate(columns[c]) if columns[c] else np.array([], dtype=object)
        for c in schema.names
    }
    return pa.table(
        {
            c: pa.array(
                merged[c].tolist() if merged[c].dtype == object else merged[c],
                type=schema.field(c).type,
            )
            for c in schema.names
        }
    )


def run_shard(
    *,
    condition_slice: Mapping[str, Any],
    states_path: Path,
    model_file: Path,
    first: int,
    stop: int,
    output_table: Path,
    output_recording: Path | None = None,
    unrecorded: Path | None = None,
    nthread: int,
    rule: str,
    batch_size: int | None = None,
    repo_root: Path = REPO_ROOT,
    extra_inputs: Mapping[str, Any] | None = None,
) -> pa.Table:
    """Roll out the states with ids in [first, stop) under one condition: one shard.

    Writes the shard's rows of the rollout table (its stamp with the sha256 of its rows,
    `provenance.ROWS_KEY` under `extra`) and (given `output_recording`, a folder) the
    trajectory of every episode that `recording.episodes` asks for (`all` or `failed`) as a
    Rerun recording, one .rrd per episode, written while the next batch runs. Memory is bounded
    by the batch and the shard, never by the number of states. `unrecorded` is the shard's
    recordings folder when `recording.episodes` is none: an earlier run's is removed once the
    table is written, so that no reader takes its recordings for this run's. The log's
    `# phases:` line says where the time went (`mjtrial.sim.phases`).
    """
    with phases.clocked() as clock:
        table = _run_shard(
            condition_slice=condition_slice,
            states_path=states_path,
            model_file=model_file,
            first=first,
            stop=stop,
            output_table=output_table,
            output_recording=output_recording,
            unrecorded=unrecorded,
            nthread=nthread,
            rule=rule,
            batch_size=batch_size,
            repo_root=repo_root,
            extra_inputs=extra_inputs,
        )
    log.info("%s", clock.line())
    return table


def _run_shard(
    *,
    condition_slice: Mapping[str, Any],
    states_path: Path,
    model_file: Path,
    first: int,
    stop: int,
    output_table: Path,
    output_recording: Path | None,
    unrecorded: Path | None,
    nthread: int,
    rule: str,
    batch_size: int | None,
    repo_root: Path,
    extra_inputs: Mapping[str, Any] | None,
) -> pa.Table:
    with phases.phase("task + states"):
        bound = condition_task(condition_slice, model_file, repo_root=repo_root)
        drop_asset_cache()  # a job process compiles its model once
        task = bound.task
        values = read_state_values(states_path, task, first=first, stop=stop)
    condition = condition_slice["condition"]
    recorded = condition_slice["recording"].get("episodes", "all")
    inputs = {
        "states": states_path,
        **model_inputs(model_file),
        **task_inputs(condition_slice["task"], repo_root=repo_root),
        **condition_policy_inputs(condition_slice, repo_root=repo_root),
        # a benchmark's evaluation: the parameter file it ran; another MuJoCo: its env's lock
        **(extra_inputs or {}),
    }
    with phases.phase("stamp"):
        stamp = make_stage_stamp(
            rule,
            dict(condition_slice),
            inputs,
            threads=nthread,
            repo_root=repo_root,
            extra=policy_settings(condition_slice),
        )
    columns: dict[str, list[np.ndarray]] = {c: [] for c in rollout_columns(task)}
    progress = Progress(f"{rule}", total=stop - first)

    def batches() -> Iterator[engine.Batch]:
        for batch in condition_batches(
            bound, condition_slice, values, nthread=nthread, batch_size=batch_size
        ):
            columns["state_id"].append(batch.values["state_id"])
            for c in rollout_columns(task)[1:]:
                columns[c].append(batch.outcome[c])
            yield batch
            progress.advance(len(batch.outcome["success"]))

    def episodes() -> Iterator[recording.EpisodeRecord]:
        for batch in batches():
            for episode in episode_records(task, batch):
                if recorded == "all" or not episode.success:
                    yield episode

    if output_recording is None:
        for _ in batches():
            pass
    else:
        from mjtrial import recording  # rerun where a job records only (`recording_spec`)

        with phases.phase("recording (main thread)"):
            recording.write_condition_recordings(
                output_recording,
                spec=recording_spec(
                    bound,
                    engine.episode_steps(bound, condition_parameters(bound, condition_slice)),
                    condition_slice["recording"]["rate_hz"],
                ),
                condition=condition,
                episodes=episodes(),
                stamp=stamp,
            )
    with phases.phase("table + row hash"):
        table = outcome_table(task, columns)
        # The table's stamp also records the hash of its rows (the arrays in hand, no re-read):
        # every reader refuses the shard once a row is edited (`provenance.read_checked_table`).
        rows = {provenance.ROWS_KEY: provenance.rows_sha256(table)}
    with phases.phase("write table"):
        provenance.write_parquet(
            table, output_table, {**stamp, "extra": {**stamp["extra"], **rows}}
        )
        if unrecorded is not None:
            atomic.remove_folder(unrecorded)
    log.info(
        "%s: %d/%d successes -> %s",
        rule,
        int(np.asarray(table.column("success")).sum()),
        table.num_rows,
        output_table,
    )
    return table


def gather_condition(
    *,
    condition_slice: Mapping[str, Any],
    shard_tables: Sequence[Path],
    model_file: Path,
    output_table: Path,
    output_nominal: Path,
    rule: str,
    repo_root: Path = REPO_ROOT,
    extra_inputs: Mapping[str, Any] | None = None,
) -> pa.Table:
    """The condition's rollout table from its shards' (in state order; a shard whose rows are
    not the ones its stamp records is refused, `provenance.read_checked_table`), and the
    nominal state's episode (each state parameter at its nominal value) for the "nominal state
    alone" mistake."""
    bound = condition_task(condition_slice, model_file, repo_root=repo_root)
    tables = [provenance.read_checked_table(p).replace_schema_metadata(None) for p in shard_tables]
    table = pa.concat_tables(tables) if tables else rollout_schema(bound.task).empty_table()
    ids = table.column("state_id").to_numpy()
    if not np.array_equal(ids, np.arange(len(ids))):
        raise ValueError(
            f"{rule}: the shards' state ids are not 0..{len(ids) - 1} in order; expected every "
            "shard once"
        )
    nominal = nominal_episode(condition_slice, model_file, repo_root=repo_root, bound=bound)
    inputs = {
        "shards": list(shard_tables),
        **model_inputs(model_file),
        **task_inputs(condition_slice["task"], repo_root=repo_root),
        **condition_policy_inputs(condition_slice, repo_root=repo_root),
        **(extra_inputs or {}),  # another MuJoCo version's environment: its lock
    }
    stamp = make_stage_stamp(
        rule,
        dict(condition_slice),
        inputs,
        repo_root=repo_root,
        extra=policy_settings(condition_slice),
    )
    provenance.write_parquet(table, output_table, stamp)
    provenance.write_json(nominal, output_nominal, stamp)
    log.info(
        "%s: %d shards, %d/%d successes -> %s",
        rule,
        len(shard_tables),
        int(np.asarray(table.column("success")).sum()),
        table.num_rows,
        output_table,
    )
    return table


def nominal_episode(
    condition_slice: Mapping[str, Any],
    model_file: Path,
    *,
    repo_root: Path = REPO_ROOT,
    bound: BoundTask | None = None,
) -> dict[str, Any]:
    """The nominal state's episode under a condition: what a careless evaluation runs alone."""
    bound = bound or condition_task(condition_slice, model_file, repo_root=repo_root)
    task = bound.task
    nominal = {p.name: p.nominal_value for p in task.state_parameters}
    batch = next(
        condition_batches(
            bound,
            condition_slice,
            {k: np.array([v]) for k, v in nominal.items()},
            nthread=1,
        )
    )
    out = batch.outcome
    return {
        "condition": condition_slice["condition"],
        "state": {"state_id": None, **nominal},
        "success": bool(out["success"][0]),
        **{m.name: float(out[m.name][0]) for m in recorded_measures(task)},
        "failure_category": out["failure_category"][0],
    }
