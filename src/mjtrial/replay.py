"""Replay one episode: re-simulate it from the stored states, the model and the config, write
its trajectory at full simulation rate, and check it reproduces what the pipeline recorded.

`read_episode` reads a logged episode's time series back from any `.rrd` for scripts and
notebooks (see the README for the entity layout).
"""

from __future__ import annotations

import shutil
import subprocess
import sys
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow.parquet as pq

from mjtrial import provenance, recording
from mjtrial.config import check_config, read_config_file
from mjtrial.design.conditions import all_conditions, variant_names
from mjtrial.files.layout import CONFIG_FILE, NOMINAL, RESULTS_DIR, Layout, shard_ids
from mjtrial.recording import write_episode_recording
from mjtrial.sim import engine
from mjtrial.stages.rollout import (
    condition_batches,
    condition_parameters,
    condition_policy_inputs,
    condition_task,
    episode_records,
    policy_settings,
    read_state_values,
    recording_spec,
    rollout_columns,
)
from mjtrial.stages.stamping import config_slice, model_inputs, task_inputs
from mjtrial.task import Measure

__all__ = ["NotYetWritten", "ReplayMismatch", "Replay", "read_episode", "replay_episode"]

# Compared exactly, every column of the rollout table: the engine is deterministic for a given
# MuJoCo build and CPU.


class ReplayMismatch(RuntimeError):
    """The re-simulated episode differs from the recorded one."""


@dataclass(frozen=True)
class Replay:
    """What a replay produced: the episode's outcome and where its recording went."""

    condition: str  # "<condition>", or "<variant>/<condition>" on a simulator variant
    state_id: int
    outcome: dict[str, Any]  # the rollout table's row, by column
    recording: Path
    measures: tuple[Measure, ...] = ()  # the task's own measures, for the outcome's words

    def describe(self) -> str:
        """The outcome in one line: success or failure (category), and each task measure."""
        if self.outcome["success"]:
            words = ["success"]
        else:
            words = [f"failure ({self.outcome['failure_category']})"]
        for m in self.measures:
            value = self.outcome[m.name]
            shown = f"{value:.4g}" if isinstance(value, float) else str(value)
            words.append(f"{m.name} {shown}{' ' + m.unit if m.unit else ''}")
        return f"{self.condition} state {self.state_id}: " + ", ".join(words)


def _recorded_row(table_path: Path, state_id: int) -> dict[str, Any]:
    table = pq.read_table(table_path)
    ids = table.column("state_id").to_numpy()
    rows = np.flatnonzero(ids == state_id)
    if rows.size != 1:
        raise KeyError(f"{table_path}: no episode for state {state_id}")
    return {c: table.column(c)[int(rows[0])].as_py() for c in table.column_names}


def _is_nan(value: Any) -> bool:
    return isinstance(value, float) and value != value


def read_episode(
    path: str | Path,
    *,
    condition: str | None = None,
    state_id: int | None = None,
    variant: str = NOMINAL,
) -> dict[str, np.ndarray]:
    """One recorded episode's time series, wherever it is (`mjtrial.recording.read_episode`).

    `path` is a results folder (`results/<experiment>`: the episode is looked up in its
    condition's shards, of `variant`), a condition's folder, a shard's folder or a `.rrd` file;
    a file holding one episode's recording alone needs no `condition` and `state_id`.

    Raises:
      KeyError: it was not recorded (`recording.episodes: failed` records failures only,
        `none` nothing): `mjtrial replay` re-simulates any episode.
    """
    path = Path(path)
    layout = Layout(path)
    if path.is_dir() and layout.rollouts_dir(variant).is_dir():
        if condition is None:
            raise ValueError(f"{path}: a results folder: give condition and state_id")
        path = layout.recordings(condition, variant)
    return recording.read_episode(path, condition=condition, state_id=state_id)


class OutputRefused(ValueError):
    """`mjtrial replay --output` names a file it must not write."""


def check_output(output: Path, *, results: Path, force: bool) -> None:
    """Refuse to write a replay where it could destroy something: a pipeline output, or any
    file that an earlier replay did not write (`force` allows the latter only)."""
    output, results = Path(output).resolve(), Path(results).resolve()
    inside = output.is_relative_to(results)
    in_output_folder = any(provenance.is_recording_folder(p) for p in output.parents)
    if inside and (output.suffix != ".rrd" or output.is_dir() or in_output_folder):
        raise OutputRefused(
            f"--output {output}: inside the results folder {results}; expected a new .rrd file "
            "there, or a path outside it"
        )
    if not output.exists():
        return
    try:
        ours = provenance.read_stamp(output).get("rule") == "replay"
    except (OSError, ValueError):
        ours = False
    if ours:
        return
    if inside:
        raise OutputRefused(
            f"--output {output}: an output of the pipeline; expected a new .rrd file "
            "(the pipeline's files are never overwritten)"
        )
    if not force:
        raise OutputRefused(
            f"--output {output}: exists and was not written by mjtrial replay; expected a new "
            "file (pass --force to overwrite it)"
        )


class NotYetWritten(FileNotFoundError):
    """An input of the replay that the run has not written (yet)."""


def check_inputs(layout: Layout, config: Mapping[str, Any], condition: str, variant: str) -> None:
    """Refuse, in words and before any work, a replay whose inputs the run has not written:
    the states, and the condition's gathered table (written once all its shards have run; a
    run still going has shard tables and no gathered table)."""
    if not layout.states.is_file():
        raise NotYetWritten(
            f"{layout.states}: not written; the run has not drawn its initial states yet "
            "(run `snakemake -c2`, or wait for the run going on)"
        )
    table = layout.rollout_table(condition, variant)
    if table.is_file():
        return
    shards = shard_ids(config["states"]["n"], config["rollout"]["shard_size"])
    written = sum(layout.shard_table(condition, s, variant).is_file() for s in shards)
    ran = (
        f"{written} of its {len(shards)} shards have run"
        if written
        else f"none of its {len(shards)} shards has run"
    )
    raise NotYetWritten(
        f"{table}: not written yet; a condition's episodes are gathered into it once all its "
        f"shards have run, and {ran}. Replay reads that table: wait for the run to finish "
        "(or finish it with `snakemake -c2`), then replay"
    )


def replay_episode(
    *,
    condition: str,
    state_id: int,
    variant: str = NOMINAL,
    results_dir: Path | None = None,
    output: Path | None = None,
    config_path: Path | None = None,
    repo_root: Path | None = None,
    force: bool = False,
) -> Replay:
    """Re-simulate one episode, write its `.rrd` at full rate, and check it against the record.

    `variant` is a simulator variant of the config's `variants` (the sensitivity study's
    rollouts), or the model as committed. `results_dir` is the experiment's folder (default:
    `results/<experiment>` of the config).

    `output` (default: `replays/<experiment folder>/<condition>_state<id>.rrd` in the
    repository, outside the sealed results folder) is guarded (`check_output`) before any work:
    inside the results folder only a new `.rrd`, and never over a file that an earlier replay
    did not write, unless `force`.

    Raises:
      ReplayMismatch: the outcome or final state differs from `rollouts/<condition>.parquet`;
        the message says what differs and, when they differ, the MuJoCo version and CPU of
        both runs.
      KeyError: unknown condition, variant or state.
    """
    repo_root = Path.cwd() if repo_root is None else repo_root
    config_path = config_path or repo_root / CONFIG_FILE
    # what the inputs are named by is read first; the config's check (its model, task and
    # policy files, episodes of its own) only once the inputs are known to be there
    config = read_config_file(config_path)
    try:
        conditions = all_conditions(config)
        shard_ids(config["states"]["n"], config["rollout"]["shard_size"])
        str(config["experiment"])
    except (KeyError, TypeError, AttributeError):  # a malformed config: its check says where
        check_config(config, source=str(config_path), repo_root=repo_root)
        raise
    if condition not in conditions:
        raise KeyError(
            f"condition {condition!r}: expected one of {sorted(conditions)}, the conditions of "
            f"experiment {config['experiment']!r} in {config_path}; for another experiment give "
            "its results folder or --config"
        )
    variants = variant_names(config)
    if variant != NOMINAL and variant not in variants:
        raise KeyError(
            f"variant {variant!r}: expected one of {[NOMINAL, *variants]} ({config_path})"
        )
    if results_dir is None:
        layout = Layout.of(config["experiment"], base=repo_root / RESULTS_DIR)
    else:
        layout = Layout(results_dir)
    output = output or layout.replay(condition, state_id, variant, repo_root=repo_root)
    check_output(output, results=layout.root, force=force)
    check_inputs(layout, config, condition, variant)
    check_config(config, source=str(config_path), repo_root=repo_root)
    table_path = layout.rollout_table(condition, variant)
    recorded = _recorded_row(table_path, state_id)
    recorded_stamp = provenance.read_stamp(table_path)
    qualified = condition if variant == NOMINAL else f"{variant}/{condition}"
    slice_ = config_slice("rollout", config, condition=qualified)
    if provenance.config_hash(slice_) != recorded_stamp["config_slice_sha256"]:
        raise ReplayMismatch(
            f"{table_path}: recorded with a different config for {qualified!r} than "
            f"{config_path} has now; rerun `snakemake -c2` first"
        )

    model_file = repo_root / config["model"]
    bound = condition_task(slice_, model_file, repo_root=repo_root)
    ids = pq.read_table(layout.states, columns=["state_id"]).column("state_id").to_numpy()
    if state_id not in ids:
        raise KeyError(f"{layout.states}: no state {state_id}")
    values = read_state_values(layout.states, bound.task, first=state_id, stop=state_id + 1)
    batch = next(condition_batches(bound, slice_, values, nthread=1))
    columns = rollout_columns(bound.task)
    replayed = {"state_id": state_id, **{c: batch.outcome[c][0] for c in columns[1:]}}
    replayed = {k: (v.item() if hasattr(v, "item") else v) for k, v in replayed.items()}

    stamp = provenance.make_stamp(
        rule="replay",
        config_slice=slice_,
        inputs={
            "states": layout.states,
            **model_inputs(model_file),
            **task_inputs(config["task"], repo_root=repo_root),
            **condition_policy_inputs(slice_, repo_root=repo_root),
        },
        repo_dir=repo_root,
        extra={
            "replay_of": {"condition": qualified, "state_id": state_id},
            **(policy_settings(slice_) or {}),
        },
    )
    [episode] = episode_records(bound.task, batch)
    write_episode_recording(
        output,
        spec=recording_spec(
            bound,
            engine.episode_steps(bound, condition_parameters(bound, slice_)),
            rate_hz=1.0 / bound.model.opt.timestep,
        ),
        condition=condition,
        episode=episode,
        stamp=stamp,
    )

    differences = [
        f"{c}: recorded {recorded[c]!r}, replayed {replayed[c]!r}"
        for c in columns
        if c in recorded
        and recorded[c] != replayed[c]
        and not (recorded[c] in (None, "") and replayed[c] in (None, ""))
        and not (_is_nan(recorded[c]) and _is_nan(replayed[c]))
    ]
    if differences:
        now = (
            provenance.library_versions()["mujoco"],
            provenance.platform_fingerprint()["cpu_model"],
        )
        then = recorded_stamp["versions"]["mujoco"], recorded_stamp["platform"]["cpu_model"]
        where = ""
        if now != then:
            where = (
                f" (recorded with MuJoCo {then[0]} on {then[1]}; "
                f"replayed with MuJoCo {now[0]} on {now[1]})"
            )
        raise ReplayMismatch(
            f"{qualified} state {state_id} does not reproduce: " + "; ".join(differences) + where
        )
    return Replay(
        condition=qualified,
        state_id=state_id,
        outcome=replayed,
        recording=output,
        measures=bound.task.own_measures,
    )


def open_viewer(path: Path) -> subprocess.Popen | None:
    """Spawn the Rerun viewer on `path` (the `rerun` command installed with rerun-sdk)."""
    exe = Path(sys.executable).parent / "rerun"
    command = str(exe) if exe.exists() else shutil.which("rerun")
    if command is None:
        return None
    return subprocess.Popen([command, str(path)])
