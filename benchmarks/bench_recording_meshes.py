"""Benchmark: the disk a model with meshes costs per recorded episode, and in failures.rrd.

The model is gymnasium-robotics' Fetch (18 STL meshes, tasks/fetch_pick/assets/fetch). Its
episodes come from a plain mj_step loop (the mocap target wanders, the fingers get random
ctrl), recorded as the rollout stage records a condition: every `log_every`-th step of each
1,000-step episode. It prints an episode file's size with the meshes in every file (as before
the mesh store) and with the folder's mesh store, the size of a failures.rrd gathered from all
the episodes (each a failure), and what an episode's file is spent on: its static chunks alone
and its per-step chunks alone, each written as a file (every chunk costs a few kB of schema
and index whatever its size, so the two add up to about the whole):

    python benchmarks/bench_recording_meshes.py                  # 200 episodes at 100 Hz
    python benchmarks/bench_recording_meshes.py --episodes 50 --rate-hz 500
"""

from __future__ import annotations

import argparse
import statistics
import tempfile
import time
from pathlib import Path

import mujoco
import numpy as np
from rerun.chunk import ChunkStore, RrdReader

from mjtrial import REPO_ROOT
from mjtrial.recording import write_condition_recordings, write_failures_rrd
from mjtrial.recording.names import MESH_STORE_FILE
from mjtrial.recording.series import Signal
from mjtrial.recording.write import EpisodeRecord, EpisodeStores, RecordingSpec
from mjtrial.sim.physics import FULLPHYSICS

FETCH = REPO_ROOT / "tasks" / "fetch_pick" / "assets" / "fetch" / "pick_and_place.xml"
STAMP = {"mjtrial_stamp": 1, "rule": "bench_recording_meshes"}


def episode(model: mujoco.MjModel, seed: int, n_steps: int) -> EpisodeRecord:
    data = mujoco.MjData(model)
    rng = np.random.default_rng(seed)
    nstate = mujoco.mj_stateSize(model, FULLPHYSICS)
    physics, ctrl = np.empty((n_steps, nstate)), np.empty((n_steps, model.nu))
    sensordata = np.empty((n_steps, model.nsensordata))
    for i in range(n_steps):
        data.mocap_pos[0] += rng.uniform(-2e-3, 2e-3, 3)
        data.ctrl[:] = rng.uniform(-0.02, 0.02, model.nu)
        ctrl[i] = data.ctrl
        mujoco.mj_step(model, data)
        mujoco.mj_getState(model, data, physics[i], FULLPHYSICS)
        sensordata[i] = data.sensordata
    return EpisodeRecord(
        state_id=seed,
        values={"seed": float(seed)},
        physics=physics,
        sensordata=sensordata,
        ctrl=ctrl,
        success=False,
        measures={},
        failure_category="dropped",
    )


def part_sizes(path: Path, scratch: Path) -> dict[str, int]:
    """Bytes on disk of one recording's static chunks alone and its per-step chunks alone
    (each written as a file of its own: its chunks and their share of the file's index)."""
    reader = RrdReader(path)
    [entry] = reader.recordings()
    chunks = list(reader.store(store=entry).stream())
    out = {}
    for part, static in (("static", True), ("per step", False)):
        target = scratch / f"{part}.rrd"
        store = ChunkStore.from_chunks([c for c in chunks if c.is_static == static])
        store.write_rrd(str(target), application_id="mjtrial", recording_id=entry.recording_id)
        out[part] = target.stat().st_size
        out[f"{part} chunks"] = sum(c.is_static == static for c in chunks)
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--episodes", type=int, default=200)
    parser.add_argument("--steps", type=int, default=1000)
    parser.add_argument("--rate-hz", type=float, default=100.0)
    args = parser.parse_args()
    model = mujoco.MjModel.from_xml_path(str(FETCH))
    log_every = max(1, round(1.0 / (args.rate_hz * model.opt.timestep)))
    gripper = model.body("robot0:gripper_link").id
    spec = RecordingSpec(
        model=model,
        signals=[Signal("time", gripper, "time", lambda rows, sensors, ctrl: rows[:, 0])],
        state_names=["seed"],
        measure_names=[],
        n_steps=args.steps,
        log_every=log_every,
    )
    t0 = time.perf_counter()
    episodes = [episode(model, seed, args.steps) for seed in range(args.episodes)]
    simulated = time.perf_counter() - t0

    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        folder = tmp / "c"
        t0 = time.perf_counter()
        write_condition_recordings(
            folder, spec=spec, condition="c", episodes=iter(episodes), stamp=STAMP
        )
        written = time.perf_counter() - t0
        files = sorted(folder.glob("c-state-*.rrd"))
        sizes = [f.stat().st_size for f in files]
        store = (folder / MESH_STORE_FILE).stat().st_size
        parts = part_sizes(files[0], tmp)

        # the meshes in every recording, as before the mesh store
        inline = EpisodeStores(spec, condition="c", stamp=STAMP)
        [group] = inline.groups(episodes[:1])
        [(recording_id, whole)] = inline.build(group)
        target = tmp / "inline.rrd"
        whole.write_rrd(str(target), application_id="mjtrial", recording_id=recording_id)
        inline_size = target.stat().st_size

        failures = tmp / "failures.rrd"
        t0 = time.perf_counter()
        n_failures = write_failures_rrd(failures, [folder], stamp=STAMP)
        gathered = time.perf_counter() - t0
        failures_size = failures.stat().st_size

    print(
        f"Fetch (18 meshes, {model.nmeshvert} vertices, {model.nmeshface} triangles): "
        f"{args.episodes} episodes of {args.steps} steps, logged every {log_every} "
        f"({args.rate_hz:g} Hz, {len(group[0].rows)} rows)\n"
    )
    print(
        f"simulation {simulated:.1f} s, writing the folder {written:.1f} s, "
        f"gathering failures.rrd {gathered:.1f} s\n"
    )
    print(f"{'episode file, meshes inline (before)':<44} {inline_size / 1e3:9.1f} kB")
    print(
        f"{'episode file, with the mesh store (median)':<44} "
        f"{statistics.median(sizes) / 1e3:9.1f} kB"
    )
    for part in ("static", "per step"):
        label = f"  its {parts[part + ' chunks']} {part} chunks alone"
        print(f"{label:<44} {parts[part] / 1e3:9.1f} kB")
    print(f"{'mesh store (meshes.rrd, once per folder)':<44} {store / 1e3:9.1f} kB")
    print(f"{'folder, all episode files and the store':<44} {(sum(sizes) + store) / 1e6:9.2f} MB")
    print(f"{f'failures.rrd, {n_failures} failures':<44} {failures_size / 1e6:9.2f} MB")


if __name__ == "__main__":
    main()
