"""The rollout stage: every state under one condition, its outcomes, failures and recordings."""

from __future__ import annotations

import logging
import time
from collections.abc import Iterator, Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq

from mjtrial import REPO_ROOT, provenance, recording, taxonomy
from mjtrial.model_spec import ModelSpec
from mjtrial.protocol import (
    CONDITION_PARAMETERS,
    PROTOCOL,
    Protocol,
    condition_protocol,
    control_sequence,
)
from mjtrial.simulate import (
    BATCH_SIZE,
    EPISODE_COLUMNS,
    EpisodeBatch,
    episode_outcomes,
    iter_episode_batches,
    load_model,
)
from mjtrial.stages.stamping import make_stage_stamp, model_inputs
from mjtrial.states import InitialState, states_from_table
from mjtrial.studies.variants import variant_model

log = logging.getLogger("mjtrial")

# Columns of `rollouts/<condition>.parquet`, in order: the outcome, then the failure analysis.
ROLLOUT_COLUMNS = (*EPISODE_COLUMNS, "failure_category", "peak_slip", "peak_carriage_accel")


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


def read_states(path: Path) -> list[InitialState]:
    """The initial states stored in `states.parquet`, checked."""
    return states_from_table(pq.read_table(path), source=str(path))


def nominal_state(model: Any) -> InitialState:
    """The state a careless evaluation uses alone: no offset, no yaw, the mass as compiled."""
    return InitialState(-1, 0.0, 0.0, 0.0, float(model.body_mass[ModelSpec.of(model).cube_body]))


def condition_outcomes(
    model: Any,
    states: Sequence[InitialState],
    *,
    lift_time: float,
    thresholds: taxonomy.Thresholds,
    nthread: int,
    batch_size: int = BATCH_SIZE,
    protocol: Protocol = PROTOCOL,
) -> Iterator[tuple[EpisodeBatch, dict[str, np.ndarray]]]:
    """Each batch of episodes with its per-episode columns (`ROLLOUT_COLUMNS`)."""
    _, phase = control_sequence(lift_time, timestep=model.opt.timestep, protocol=protocol)
    for batch in iter_episode_batches(
        model,
        states,
        lift_time=lift_time,
        nthread=nthread,
        batch_size=batch_size,
        protocol=protocol,
    ):
        outcome = episode_outcomes(model, batch, lift_time=lift_time, protocol=protocol)
        traj = taxonomy.trajectories_from_batch(
            model, batch, phase=phase, home_xy=(protocol.home_x, 0.0)
        )
        yield batch, outcome | taxonomy.classify(traj, outcome["success"], thresholds)


def log_every(rate_hz: float, timestep: float) -> int:
    """Physics steps between logged steps for a logging rate (at least every step)."""
    return max(1, round(1.0 / (rate_hz * timestep)))


def episode_records(
    batch: EpisodeBatch, outcome: Mapping[str, np.ndarray]
) -> Iterator[recording.EpisodeRecord]:
    """The batch's episodes as `recording.EpisodeRecord`s, with their outcomes."""
    for i, state in enumerate(batch.states):
        yield recording.EpisodeRecord(
            state=state,
            physics=batch.physics[i],
            sensordata=batch.sensordata[i],
            success=bool(outcome["success"][i]),
            final_height=float(outcome["final_height"][i]),
            failure_category=outcome["failure_category"][i],
        )


# The table's types, fixed: a shard whose every episode succeeded has no category to infer a
# type from, and every shard's table must concatenate into the condition's.
ROLLOUT_SCHEMA = pa.schema(
    [
        ("state_id", pa.int64()),
        ("success", pa.bool_()),
        ("final_height", pa.float64()),
        ("final_x", pa.float64()),
        ("final_y", pa.float64()),
        ("steps_simulated", pa.int64()),
        ("nonfinite", pa.bool_()),
        ("warning", pa.string()),
        ("failure_category", pa.string()),
        ("peak_slip", pa.float64()),
        ("peak_carriage_accel", pa.float64()),
    ]
)
EPISODES_RECORDED = ("all", "failed", "none")  # config recording.episodes


def condition_model(condition_slice: Mapping[str, Any], model_file: Path) -> Any:
    """The model a condition runs on: the committed one, or the slice's variant of it."""
    variant = condition_slice.get("variant")
    if variant is None:
        return load_model(model_file)
    model, _ = variant_model(
        model_file, variant["overrides"], key_prefix=f"variants.{variant['name']}"
    )
    return model


def slice_protocol(condition_slice: Mapping[str, Any]) -> Protocol:
    """The protocol of a rollout config slice: its condition's parameters set."""
    return condition_protocol(
        {
            k: condition_slice[k]
            for k in ("lift_time", *CONDITION_PARAMETERS)
            if k in condition_slice
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
    nthread: int,
    rule: str,
    batch_size: int = BATCH_SIZE,
    repo_root: Path = REPO_ROOT,
) -> pa.Table:
    """Roll out the states with ids in [first, stop) under one condition: one shard.

    Writes the shard's rows of the rollout table and (given `output_recording`, a folder) the
    trajectory of every episode that `recording.episodes` asks for (`all` or `failed`) as a
    Rerun recording, one .rrd per episode, written while the next batch runs. Memory is bounded
    by the batch and the shard, never by the number of states.
    """
    model = condition_model(condition_slice, model_file)
    states = [s for s in read_states(states_path) if first <= s.state_id < stop]
    if len(states) != stop - first:
        raise ValueError(f"{states_path}: expected states {first}..{stop - 1}, found {len(states)}")
    condition = condition_slice["condition"]
    lift_time = float(condition_slice["lift_time"])
    protocol = slice_protocol(condition_slice)
    thresholds = taxonomy.Thresholds.from_config(condition_slice["failure_taxonomy"])
    recorded = condition_slice["recording"].get("episodes", "all")
    inputs = {"states": states_path, **model_inputs(model_file)}
    stamp = make_stage_stamp(rule, dict(condition_slice), inputs, repo_root=repo_root)
    columns: dict[str, list[np.ndarray]] = {c: [] for c in ROLLOUT_COLUMNS}
    progress = Progress(f"{rule}", total=len(states))

    def episodes() -> Iterator[recording.EpisodeRecord]:
        for batch, outcome in condition_outcomes(
            model,
            states,
            lift_time=lift_time,
            thresholds=thresholds,
            nthread=nthread,
            batch_size=batch_size,
            protocol=protocol,
        ):
            for c in ROLLOUT_COLUMNS:
                columns[c].append(outcome[c])
            for episode in episode_records(batch, outcome):
                if recorded == "all" or not episode.success:
                    yield episode
            progress.advance(len(batch.states))

    if output_recording is None:
        for _ in episodes():
            pass
    else:
        recording.write_condition_recordings(
            output_recording,
            model=model,
            condition=condition,
            episodes=episodes(),
            ctrl=control_sequence(lift_time, timestep=model.opt.timestep, protocol=protocol)[0],
            stamp=stamp,
            log_every=log_every(condition_slice["recording"]["rate_hz"], model.opt.timestep),
        )
    merged = {c: np.concatenate(v) for c, v in columns.items()}
    table = pa.table(
        {
            c: pa.array(
                merged[c].tolist() if merged[c].dtype == object else merged[c],
                type=ROLLOUT_SCHEMA.field(c).type,
            )
            for c in ROLLOUT_COLUMNS
        }
    )
    provenance.write_parquet(table, output_table, stamp)
    log.info(
        "%s: %d/%d successes (lift %g s) -> %s",
        rule,
        int(merged["success"].sum()),
        len(states),
        lift_time,
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
) -> pa.Table:
    """The condition's rollout table from its shards' (in state order), and the nominal state's
    episode (no offset, no yaw, the mass as compiled) for the "nominal state alone" mistake."""
    tables = [pq.read_table(p).replace_schema_metadata(None) for p in shard_tables]
    table = pa.concat_tables(tables) if tables else ROLLOUT_SCHEMA.empty_table()
    ids = table.column("state_id").to_numpy()
    if not np.array_equal(ids, np.arange(len(ids))):
        raise ValueError(
            f"{rule}: the shards' state ids are not 0..{len(ids) - 1} in order; expected every "
            "shard once"
        )
    nominal = nominal_episode(condition_slice, model_file)
    inputs = {"shards": list(shard_tables), **model_inputs(model_file)}
    stamp = make_stage_stamp(rule, dict(condition_slice), inputs, repo_root=repo_root)
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


def nominal_episode(condition_slice: Mapping[str, Any], model_file: Path) -> dict[str, Any]:
    """The nominal state's episode under a condition: what a careless evaluation runs alone."""
    model = condition_model(condition_slice, model_file)
    nominal = nominal_state(model)
    _, outcome = next(
        condition_outcomes(
            model,
            [nominal],
            lift_time=float(condition_slice["lift_time"]),
            thresholds=taxonomy.Thresholds.from_config(condition_slice["failure_taxonomy"]),
            nthread=1,
            protocol=slice_protocol(condition_slice),
        )
    )
    return {
        "condition": condition_slice["condition"],
        "state": nominal.__dict__ | {"state_id": None},
        "success": bool(outcome["success"][0]),
        "final_height": float(outcome["final_height"][0]),
        "failure_category": outcome["failure_category"][0],
    }
