"""What a config will cost, estimated before any work, and the limits it must keep.

A typo can ask for hours and gigabytes: a timestep of 1e-6 s makes millions of steps per
episode (the preflight alone then takes minutes, a rollout batch wants gigabytes), and a shard
size of 1 with 20,000 states makes 40,000 jobs whose dry run alone takes minutes. These checks
run on the config and the compiled model only, before the preflight simulates anything, and
each refusal names the key and the figure.
"""

from __future__ import annotations

from collections.abc import Iterator, Mapping
from typing import Any

import mujoco
import psutil

from mjtrial.files.layout import evaluation_shard_size, shard_ids
from mjtrial.sim import engine
from mjtrial.task import BoundTask, call

# Steps of one episode: the preflight steps every condition's nominal episode, and a batch holds
# every step's state; the built-in episode is about 2,100 steps (2 ms), 10 s holds at 0.1 ms
# about 500,000.
MAX_STEPS_PER_EPISODE = 500_000
# Rollout jobs (shards x conditions x models): Snakemake's dry run costs about 2 ms a job and
# grows its memory with them (40,000 jobs: 89 s, 1.5 GB).
MAX_ROLLOUT_JOBS = 5_000
# A rollout process before its batch: interpreter, MuJoCo, pyarrow, Rerun (measured 250-360 MB).
JOB_BASE_BYTES = 360e6


def job_memory_limit() -> float:
    """Bytes a rollout job may use: half the machine's memory (the default profile runs two
    side by side)."""
    return psutil.virtual_memory().total / 2


def batch_bytes(model: mujoco.MjModel, steps: int) -> float:
    """A batch's trajectories, sensor values and controls, held twice (the engine's output and
    the recording's copy): `engine.BATCH_BYTES`, or one episode's when that is more."""
    return engine.batch_size_for(model, steps) * engine.episode_bytes(model, steps)


def episode_problems(
    conditions: Mapping[str, Mapping[str, Any]],
    bound: BoundTask,
    *,
    timestep_key: str,
    rate_hz: float,
) -> Iterator[tuple[str, str]]:
    """(key, expectation) for each condition the model cannot afford or resolve: what the
    task's `check_condition` says (a hold shorter than one step), too many steps, too much
    memory per job, a logging rate slower than the episode. `timestep_key` names where the
    timestep comes from (`model`, `variants.<name>.option.timestep`)."""
    task, model = bound.task, bound.model
    dt = float(model.opt.timestep)
    limit = job_memory_limit()
    parameters = {p.name for p in task.protocol_parameters}
    for name, condition in conditions.items():
        params = task.parameters(condition)
        check = task.check_condition
        problems = list(call(task, "check_condition", check, model, params)) if check else []
        for what, expectation in problems:
            yield (f"conditions.{name}.{what}" if what in parameters else timestep_key), expectation
        steps = engine.episode_steps(bound, condition)
        if steps > MAX_STEPS_PER_EPISODE:
            yield timestep_key, (
                f"timestep {dt:g} s gives {steps:,} steps per episode under condition {name!r}; "
                f"expected at most {MAX_STEPS_PER_EPISODE:,}"
            )
            continue
        need = JOB_BASE_BYTES + batch_bytes(model, steps)
        if need > limit:
            yield timestep_key, (
                f"condition {name!r}: a rollout job would need about {need / 1e9:.1f} GB "
                f"({steps:,} steps per episode at {dt:g} s, batches of "
                f"{engine.batch_size_for(model, steps)}); expected at most {limit / 1e9:.1f} GB, "
                "half this machine's memory"
            )
        logged_every = max(1, round(1.0 / (rate_hz * dt)))
        if logged_every >= steps:
            yield "recording.rate_hz", (
                f"{rate_hz:g} Hz logs one step every {logged_every * dt:g} s, which leaves only "
                f"the last step of a {steps * dt:g} s episode (condition {name!r}); expected a "
                f"rate above {1 / (steps * dt):.3g} Hz"
            )


def rollout_jobs(config: Mapping[str, Any], n_conditions: int) -> int:
    """Rollout jobs of the built-in run and the studies: shards x (the nominal model's
    conditions + each variant's design conditions)."""
    shards = len(shard_ids(config["states"]["n"], evaluation_shard_size(config)))
    variants = len(config.get("variants") or {})
    return shards * (n_conditions + variants * len(config["conditions"]))


def job_count_problem(config: Mapping[str, Any], n_conditions: int) -> tuple[str, str] | None:
    jobs = rollout_jobs(config, n_conditions)
    if jobs <= MAX_ROLLOUT_JOBS:
        return None
    key = "stopping.look_every" if "stopping" in config else "rollout.shard_size"
    return key, (
        f"{evaluation_shard_size(config):,} states per shard make {jobs:,} rollout jobs for "
        f"{config['states']['n']:,} states; expected at most {MAX_ROLLOUT_JOBS:,} (a larger "
        f"{key.split('.')[1]})"
    )
