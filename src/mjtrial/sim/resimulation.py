"""Episodes re-simulated by `mjtrial verify`, each alone: in this process, or in the
environment of the MuJoCo version a variant names (`mjtrial.sim.simenv`).

A variant on another MuJoCo version ran its rollouts in that version's Python; verify runs the
same functions there (`python -m mjtrial.sim.resimulation REQUEST`, as the workflow's rollout jobs
start again in that Python), one process per condition for all its sampled episodes and its
nominal episode, and compares what comes back as it compares every variant's. This module
imports no more than the rollout stage does: it starts in a fresh interpreter.
"""

from __future__ import annotations

import json
import subprocess
import sys
import tempfile
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import mujoco
import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq

import mjtrial
from mjtrial.stages.rollout import (
    condition_batches,
    condition_task,
    nominal_episode,
    outcome_table,
    read_state_values,
    rollout_columns,
)

__all__ = ["in_environment", "resimulated_outcome"]


def resimulated_outcome(
    condition_slice: Mapping[str, Any],
    model_file: Path,
    states_path: Path,
    ids: Sequence[int],
    *,
    repo_root: Path,
) -> pa.Table:
    """The rollout table's rows of the states `ids` (in that order) under a condition, each
    episode alone: not the batch it ran in (`mjtrial.sim.engine.batch_size_for` rows or the
    shard's), so a result that depends on its batch is not confirmed."""
    bound = condition_task(condition_slice, model_file, repo_root=repo_root)
    every = read_state_values(states_path, bound.task)
    values = {k: v[list(ids)] for k, v in every.items()}
    columns = rollout_columns(bound.task)
    outcome: dict[str, list[np.ndarray]] = {c: [] for c in columns}
    for batch in condition_batches(bound, condition_slice, values, nthread=1, batch_size=1):
        outcome["state_id"].append(batch.values["state_id"])
        for c in columns[1:]:
            outcome[c].append(batch.outcome[c])
    return outcome_table(bound.task, outcome)


def in_environment(
    python: Path,
    version: str,
    jobs: Mapping[str, tuple[Mapping[str, Any], Sequence[int] | None]],
    *,
    model_file: Path,
    states_path: Path,
    repo_root: Path,
) -> dict[str, Any]:
    """Run `jobs` (key -> (condition slice, state ids, or None for the nominal episode)) with
    `python`, the interpreter of MuJoCo `version`'s environment: key -> the rows
    (`resimulated_outcome`) or the nominal episode (`nominal_episode`, as JSON gives it back).

    Raises `RuntimeError` naming the interpreter when it fails, or when it runs another MuJoCo
    or another checkout's mjtrial than this one (whose code the stamps were checked against).
    """
    with tempfile.TemporaryDirectory(prefix="mjtrial-resimulation-") as folder:
        outputs = {
            key: Path(folder) / f"{i}.{'json' if ids is None else 'parquet'}"
            for i, (key, (_, ids)) in enumerate(jobs.items())
        }
        request = {
            "mujoco": version,
            "mjtrial": str(Path(mjtrial.__file__).resolve().parent),
            "model_file": str(Path(model_file).absolute()),
            "states": str(Path(states_path).absolute()),
            "repo_root": str(Path(repo_root).absolute()),
            "jobs": [
                {"slice": s, "ids": ids if ids is None else list(ids), "out": str(outputs[key])}
                for key, (s, ids) in jobs.items()
            ],
        }
        request_path = Path(folder) / "request.json"
        request_path.write_text(json.dumps(request), encoding="utf-8")
        done = subprocess.run(
            [str(python), "-m", __name__, str(request_path)],
            cwd=repo_root,
            capture_output=True,
            text=True,
        )
        if done.returncode != 0:
            last = (done.stderr.strip().splitlines() or [f"exit status {done.returncode}"])[-1]
            raise RuntimeError(f"{python}: {last}")
        return {
            key: json.loads(path.read_text(encoding="utf-8"))
            if path.suffix == ".json"
            else pq.read_table(path)
            for key, path in outputs.items()
        }


def _run(request_path: Path) -> None:
    """What `in_environment` asks, run in the environment's Python."""
    request = json.loads(Path(request_path).read_text(encoding="utf-8"))
    here = Path(mjtrial.__file__).resolve().parent
    if mujoco.__version__ != request["mujoco"] or here != Path(request["mjtrial"]):
        raise SystemExit(
            f"expected MuJoCo {request['mujoco']} and mjtrial from {request['mjtrial']}, found "
            f"MuJoCo {mujoco.__version__} and mjtrial from {here}"
        )
    repo_root, model_file = Path(request["repo_root"]), Path(request["model_file"])
    for job in request["jobs"]:
        if job["ids"] is None:
            episode = nominal_episode(job["slice"], model_file, repo_root=repo_root)
            text = json.dumps(episode, default=lambda v: v.item())
            Path(job["out"]).write_text(text, encoding="utf-8")
        else:
            table = resimulated_outcome(
                job["slice"], model_file, Path(request["states"]), job["ids"], repo_root=repo_root
            )
            pq.write_table(table, job["out"])


if __name__ == "__main__":
    _run(Path(sys.argv[1]))
