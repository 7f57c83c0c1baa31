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
    EPISODE_COLUMNS,
    EpisodeBatch,
    episode_outcomes,
    iter_episode_batches,
    load_model,
)
from mjtrial.stages.stamping import make_stage_stamp, model_inputs
from mjtrial.states import InitialState, states_from_table

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
    batch_size: int = 64,
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


def run_condition(
    *,
    condition_slice: Mapping[str, Any],
    states_path: Path,
    model_file: Path,
    output_table: Path,
    output_nominal: Path,
    output_recording: Path | None = None,
    nthread: int,
    batch_size: int = 64,
    repo_root: Path = REPO_ROOT,
    model: Any = None,
    rule: str | None = None,
) -> dict[str, np.ndarray]:
    """Roll out every state under one condition.

    Writes the per-episode table, the nominal state's episode, and (given `output_recording`,
    a folder) every episode's trajectory as a Rerun recording, one .rrd per episode, written
    batch by batch while the next batch runs. `model`, when given, is the compiled model to
    run (a variant of `model_file`), and `rule` the stamp's rule (default `rollout:<condition>`).
    """
    model = load_model(model_file) if model is None else model
    states = read_states(states_path)
    condition = condition_slice["condition"]
    lift_time = float(condition_slice["lift_time"])
    protocol = condition_protocol(
        {
            k: condition_slice[k]
            for k in ("lift_time", *CONDITION_PARAMETERS)
            if k in condition_slice
        }
    )
    thresholds = taxonomy.Thresholds.from_config(condition_slice["failure_taxonomy"])
    inputs = {"states": states_path, **model_inputs(model_file)}
    stamp = make_stage_stamp(
        rule or f"rollout:{condition}", dict(condition_slice), inputs, repo_root=repo_root
    )
    columns: dict[str, list[np.ndarray]] = {c: [] for c in ROLLOUT_COLUMNS}
    progress = Progress(f"rollout {condition}", total=len(states))

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
            yield from episode_records(batch, outcome)
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
            c: pa.array(merged[c].tolist() if merged[c].dtype == object else merged[c])
            for c in ROLLOUT_COLUMNS
        }
    )
    nominal = nominal_state(model)
    _, nominal_outcome = next(
        condition_outcomes(
            model,
            [nominal],
            lift_time=lift_time,
            thresholds=thresholds,
            nthread=1,
            protocol=protocol,
        )
    )

    provenance.write_parquet(table, output_table, stamp)
    provenance.write_json(
        {
            "condition": condition,
            "state": nominal.__dict__ | {"state_id": None},
            "success": bool(nominal_outcome["success"][0]),
            "final_height": float(nominal_outcome["final_height"][0]),
            "failure_category": nominal_outcome["failure_category"][0],
        },
        output_nominal,
        stamp,
    )
    log.info(
        "rollout %s: %d/%d successes (lift %g s) -> %s",
        condition,
        int(merged["success"].sum()),
        len(states),
        lift_time,
        output_table,
    )
    return merged
