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

from mjtrial.layout import shard_ids
from mjtrial.model_spec import FULLPHYSICS
from mjtrial.protocol import condition_protocol, episode_steps, hold_durations, hold_steps
from mjtrial.simulate import BATCH_SIZE

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
    """A batch's trajectories, states and sensor values, held twice (the engine's output and
    the recording's copy)."""
    per_step = mujoco.mj_stateSize(model, FULLPHYSICS) + model.nsensordata
    return 2.0 * BATCH_SIZE * steps * per_step * 8


def episode_problems(
    conditions: Mapping[str, Mapping[str, Any]],
    model: mujoco.MjModel,
    *,
    timestep_key: str,
    rate_hz: float,
) -> Iterator[tuple[str, str]]:
    """(key, expectation) for each condition the model cannot afford or resolve: too many
    steps, too much memory per job, a hold shorter than one step, a logging rate slower than
    the episode. `timestep_key` names where the timestep comes from (`model`,
    `variants.<name>.option.timestep`)."""
    dt = float(model.opt.timestep)
    limit = job_memory_limit()
    for name, condition in conditions.items():
        protocol = condition_protocol(condition)
        lift_time = float(condition["lift_time"])
        for what, seconds in hold_durations(lift_time, protocol).items():
            if hold_steps(seconds, dt) < 1:
                key = f"conditions.{name}.{what}" if " " not in what else timestep_key
                yield key, (
                    f"a {what} of {seconds:g} s is 0 steps of {dt:g} s; expected at least one"
                )
        steps = episode_steps(lift_time, timestep=dt, protocol=protocol)
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
                f"({steps:,} steps per episode at {dt:g} s, batches of {BATCH_SIZE}); expected at "
                f"most {limit / 1e9:.1f} GB, half this machine's memory"
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
    shards = len(shard_ids(config["states"]["n"], config["rollout"]["shard_size"]))
    variants = len(config.get("variants") or {})
    return shards * (n_conditions + variants * len(config["conditions"]))


def job_count_problem(config: Mapping[str, Any], n_conditions: int) -> tuple[str, str] | None:
    jobs = rollout_jobs(config, n_conditions)
    if jobs <= MAX_ROLLOUT_JOBS:
        return None
    return "rollout.shard_size", (
        f"{config['rollout']['shard_size']:,} states per shard make {jobs:,} rollout jobs for "
        f"{config['states']['n']:,} states; expected at most {MAX_ROLLOUT_JOBS:,} (a larger "
        "shard_size)"
    )
