"""Benchmark: the CPU a condition's replay logging costs per episode, in two layouts.

* a recording per episode, as the rollout stage writes them: each recording holds its own
  copy of the geometry, series names and properties (a chunk per entity, whatever its size)
  and is a file of its own;
* one recording for the whole condition, the episodes one after another on the timeline: a
  prototype of the writing only (nothing reads it), to put a number on what that layout would
  cost. It holds the same time series and the geometry once.

Both build and write the same episodes (the first with its writer thread, as the stage does;
CPU time counts every thread), repeats in alternating order; the figures are medians of the
repeats, per episode, and a ratio measured in this one run:

    python benchmarks/bench_recording_layout.py                 # fast lift, 200 episodes
    python benchmarks/bench_recording_layout.py --condition slow --rate-hz 25
"""

from __future__ import annotations

import argparse
import shutil
import statistics
import tempfile
import time
from pathlib import Path

import numpy as np
import pyarrow as pa
import yaml
from rerun.chunk import ChunkStore

from mjtrial import REPO_ROOT, recording
from mjtrial.files.atomic import fsync_file
from mjtrial.files.layout import CONFIG_FILE
from mjtrial.recording.arrow import chunks as recording_chunks
from mjtrial.recording.write import EpisodeStores
from mjtrial.sim import engine
from mjtrial.stages.condition import condition_parameters, condition_task
from mjtrial.stages.rollout import (
    condition_batches,
    episode_records,
    read_state_values,
    recording_spec,
)
from mjtrial.stages.stamping import config_slice, make_stage_stamp, model_inputs
from mjtrial.stages.states import build_states


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--condition", default="fast")
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--rate-hz", type=float, help="default: the config's rate_hz")
    args = parser.parse_args()
    config = yaml.safe_load((REPO_ROOT / CONFIG_FILE).read_text())
    if args.rate_hz:
        config["recording"]["rate_hz"] = args.rate_hz
    cond = config_slice("rollout", config, condition=args.condition)
    model_file = REPO_ROOT / config["model"]
    bound = condition_task(cond, model_file)

    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        states_path = tmp / "states.parquet"
        build_states(
            states_slice=config_slice("states", config), output=states_path, repo_root=REPO_ROOT
        )
        values = read_state_values(states_path, bound.task)
        episodes = [
            ep
            for batch in condition_batches(bound, cond, values, nthread=2)
            for ep in episode_records(bound.task, batch)
        ]
        stamp = make_stage_stamp(
            f"rollout:{args.condition}",
            dict(cond),
            {"states": states_path, **model_inputs(model_file)},
            repo_root=REPO_ROOT,
        )
        spec = recording_spec(
            bound,
            engine.episode_steps(bound, condition_parameters(bound, cond)),
            cond["recording"]["rate_hz"],
        )
        builder = EpisodeStores(spec, condition=args.condition, stamp=stamp)
        n_rows = len(builder.steps)
        out = tmp / "out"
        out.mkdir()

        def per_episode() -> None:  # exactly what the rollout stage calls
            recording.write_condition_recordings(
                out / args.condition,
                spec=spec,
                condition=args.condition,
                episodes=iter(episodes),
                stamp=stamp,
            )

        def per_condition() -> None:
            pending = [p for group in builder.groups(iter(episodes)) for p in group]
            series = builder.chunker.series([(p.rows, p.sensors, p.ctrl) for p in pending])
            # episode i starts at i * (its length + 1 s) on the condition's timeline
            t = series.column(0).to_numpy().astype(np.int64)
            period = int(t[n_rows - 1]) + 1_000_000_000
            t = t + np.repeat(np.arange(len(pending), dtype=np.int64) * period, n_rows)
            columns = [pa.array(t.astype("timedelta64[ns]")), *series.columns[1:]]
            series = pa.RecordBatch.from_arrays(columns, schema=series.schema)
            chunks = [c.with_entity_path(c.entity_path) for c in builder.constant]
            chunks += recording_chunks(series, temporal=True)
            target = out / f"{args.condition}.rrd"
            ChunkStore.from_chunks(chunks).write_rrd(
                target, application_id="bench", recording_id=args.condition
            )
            fsync_file(target)

        layouts = {
            "a recording per episode": per_episode,
            "a recording per condition": per_condition,
        }
        cpu: dict[str, list[float]] = {k: [] for k in layouts}
        wall: dict[str, list[float]] = {k: [] for k in layouts}
        size: dict[str, int] = {}
        for i in range(args.repeats):
            for name in layouts if i % 2 == 0 else reversed(layouts):
                c0, t0 = time.process_time(), time.perf_counter()
                layouts[name]()
                wall[name].append((time.perf_counter() - t0) / len(episodes))
                cpu[name].append((time.process_time() - c0) / len(episodes))
                size[name] = sum(f.stat().st_size for f in out.rglob("*.rrd"))
                shutil.rmtree(out)
                out.mkdir()

    print(
        f"{len(episodes)} episodes of the {args.condition} lift, {n_rows} logged steps each"
        f" ({config['recording']['rate_hz']:g} Hz), median of {args.repeats} repeats\n"
    )
    print(f"{'':<28} {'CPU ms/episode':>15} {'wall ms/episode':>16} {'MB':>7}")
    for name in layouts:
        print(
            f"{name:<28} {1e3 * statistics.median(cpu[name]):15.2f}"
            f" {1e3 * statistics.median(wall[name]):16.2f} {size[name] / 1e6:7.1f}"
        )
    ratio = statistics.median(cpu["a recording per condition"]) / statistics.median(
        cpu["a recording per episode"]
    )
    print(f"\nCPU per episode, a recording per condition / a recording per episode: {ratio:.2f}")


if __name__ == "__main__":
    main()
