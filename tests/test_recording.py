"""Tests for mjtrial.recording: recordings of real episodes, written and read back."""

from __future__ import annotations

import dataclasses
import os
import subprocess
import sys
from pathlib import Path

import mujoco
import numpy as np
import pytest
import rerun as rr
from conftest import REPO_ROOT
from gantry_lift.protocol import control_sequence
from gantry_lift.simulate import iter_episode_batches
from gantry_lift.states import InitialState

from mjtrial import model_path
from mjtrial.provenance import read_stamp
from mjtrial.recording import (
    EpisodeRecord,
    list_recordings,
    logged_steps,
    read_episode,
    read_rrd_stamp,
    recording_files,
    write_condition_recordings,
    write_episode_recording,
    write_failures_rrd,
)
from mjtrial.recording import route as route_mod
from mjtrial.recording import write as write_mod
from mjtrial.recording.write import RecordingSpec
from mjtrial.sim.physics import load_model
from mjtrial.stages.rollout import recording_spec
from mjtrial.task import BoundTask, load_task

LIFT_TIME = 0.15
CONDITION = "baseline"
STAMP = {"mjtrial_stamp": 1, "rule": "test_recording", "seeds": {"states": 7}}
CUBE_Z = 1 + 7  # physics state: time, then qpos; the cube's free joint starts at qpos[5]
STATES = [
    InitialState(0, 0.000, 0.000, 0.00, 0.30),
    InitialState(1, 0.004, -0.002, 0.20, 0.45),
    InitialState(2, -0.003, 0.001, -0.25, 0.20),
]


def _fake_home(root: Path) -> dict[str, str]:
    home = root / "home"
    return {
        "HOME": str(home),
        "XDG_CONFIG_HOME": str(home / ".config"),
        "XDG_DATA_HOME": str(home / ".local" / "share"),
        "XDG_CACHE_HOME": str(home / ".cache"),
    }


@pytest.fixture(autouse=True)
def _no_home_writes(monkeypatch: pytest.MonkeyPatch, tmp_path_factory: pytest.TempPathFactory):
    """rerun writes analytics settings under the home folder: point it at a temporary one."""
    for name, value in _fake_home(tmp_path_factory.getbasetemp()).items():
        monkeypatch.setenv(name, value)


def _rerun_cli() -> str:
    cli = Path(sys.executable).parent / "rerun"
    return str(cli) if cli.exists() else route_mod.rerun_cli()


def _verify(*paths: Path) -> subprocess.CompletedProcess[str]:
    env = {**os.environ, "CI": "1"}  # CI set: the rerun CLI writes no analytics files
    return subprocess.run(
        [_rerun_cli(), "rrd", "verify", *map(str, paths)],
        capture_output=True,
        text=True,
        env=env,
        timeout=120,
    )


# --------------------------------------------------------------------------------------------
# Fixtures: three short real episodes
# --------------------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def model() -> mujoco.MjModel:
    return load_model(model_path("gantry_gripper"))


@pytest.fixture(scope="module")
def ctrl(model: mujoco.MjModel) -> np.ndarray:
    return control_sequence(LIFT_TIME, timestep=model.opt.timestep)[0]


_GANTRY = BoundTask.of(load_task("tasks/gantry_lift/task.py", repo_root=REPO_ROOT))


def _spec(model: mujoco.MjModel, log_every: int = 5, n_steps: int | None = None) -> RecordingSpec:
    """The gantry task's recordings of LIFT_TIME episodes, every `log_every`-th step."""
    n = n_steps or len(control_sequence(LIFT_TIME, timestep=model.opt.timestep)[0])
    spec = recording_spec(BoundTask.of(_GANTRY.task, model), n, rate_hz=100.0)
    return RecordingSpec(**{**spec.__dict__, "log_every": log_every})


@pytest.fixture(scope="module")
def episodes(model: mujoco.MjModel, ctrl: np.ndarray) -> list[EpisodeRecord]:
    out = []
    for batch in iter_episode_batches(model, STATES, lift_time=LIFT_TIME, nthread=1):
        for state, physics, sensordata in zip(
            batch.states, batch.physics, batch.sensordata, strict=True
        ):
            failed = state.state_id == 1  # outcome labels are the caller's business
            out.append(
                EpisodeRecord(
                    state_id=state.state_id,
                    values={p: getattr(state, p) for p in ("dx", "dy", "yaw", "mass")},
                    physics=physics,
                    sensordata=sensordata,
                    ctrl=ctrl,
                    success=not failed,
                    measures={"final_height": float(physics[-1, CUBE_Z])},
                    failure_category="slipped" if failed else None,
                )
            )
    return out


@pytest.fixture(scope="module")
def condition_rrd(
    tmp_path_factory: pytest.TempPathFactory,
    model: mujoco.MjModel,
    ctrl: np.ndarray,
    episodes: list[EpisodeRecord],
) -> Path:
    path = tmp_path_factory.mktemp("rrd") / CONDITION  # a folder: one .rrd per episode
    mp = pytest.MonkeyPatch()  # module scope: the autouse fixture has not run yet
    for name, value in _fake_home(tmp_path_factory.getbasetemp()).items():
        mp.setenv(name, value)
    try:
        n = write_condition_recordings(
            path,
            condition=CONDITION,
            episodes=iter(episodes),  # a one-pass iterable, as the pipeline passes
            stamp=STAMP,
            spec=_spec(model, 5),
        )
    finally:
        mp.undo()
    assert n == len(episodes)
    return path


# --------------------------------------------------------------------------------------------
# A condition file
# --------------------------------------------------------------------------------------------


def test_condition_folder_holds_one_file_per_episode_and_passes_rerun_verify(
    condition_rrd: Path,
) -> None:
    files = sorted(p.name for p in condition_rrd.iterdir())
    assert files == sorted(
        [
            "blueprint.rbl",
            "recordings.json",  # the folder's stamp
            *(f"{CONDITION}-state-{s.state_id:06d}.rrd" for s in STATES),
        ]
    )
    assert recording_files(condition_rrd) == [
        condition_rrd / f"{CONDITION}-state-{s.state_id:06d}.rrd" for s in STATES
    ]
    for path in recording_files(condition_rrd):
        assert [e.recording_id for e in rr.chunk.RrdReader(path).recordings()] == [path.stem]
    result = _verify(*recording_files(condition_rrd), condition_rrd / "blueprint.rbl")
    assert result.returncode == 0, result.stderr[-2000:]


def test_list_recordings_gives_every_episode_with_its_properties(
    condition_rrd: Path, ctrl: np.ndarray, episodes: list[EpisodeRecord]
) -> None:
    recordings = list_recordings(condition_rrd)
    assert [r["recording_id"] for r in recordings] == [
        f"{CONDITION}-state-{s.state_id:06d}" for s in STATES
    ]
    for r, ep in zip(recordings, episodes, strict=True):
        s = STATES[ep.state_id]
        assert r["application_id"] == "mjtrial"
        assert r["name"] == f"{CONDITION} / state {s.state_id}"
        assert r["condition"] == CONDITION
        assert r["state_id"] == s.state_id
        assert (r["dx"], r["dy"], r["yaw"], r["mass"]) == (s.dx, s.dy, s.yaw, s.mass)
        assert r["success"] is ep.success
        assert r["final_height"] == ep.measures["final_height"]
        assert r["failure_category"] == ep.failure_category
        assert r["log_every"] == 5
        assert r["n_steps"] == len(ctrl)
        assert r["provenance"] == STAMP


def test_stamp_round_trips(condition_rrd: Path) -> None:
    assert read_rrd_stamp(condition_rrd) == STAMP
    assert read_stamp(condition_rrd) == STAMP  # provenance dispatches .rrd here


def test_read_episode_returns_the_logged_values(
    condition_rrd: Path, model: mujoco.MjModel, ctrl: np.ndarray, episodes: list[EpisodeRecord]
) -> None:
    for ep in episodes:
        got = read_episode(condition_rrd, condition=CONDITION, state_id=ep.state_id)
        steps = logged_steps(len(ctrl), 5)
        rows = ep.physics[steps]
        n = len(steps)
        assert {k: v.shape for k, v in got.items()} == {
            "time": (n,),
            "step": (n,),
            "cube_position": (n, 3),
            "cube_quat_wxyz": (n, 4),
            "carriage_position": (n, 3),
            "left_finger_position": (n, 3),
            "right_finger_position": (n, 3),
            "finger_opening": (n,),
            "ctrl_x": (n,),
            "ctrl_y": (n,),
            "ctrl_z": (n,),
            "ctrl_gripper": (n,),
            "cube_height": (n,),
            "left_normal_force": (n,),
            "right_normal_force": (n,),
        }
        np.testing.assert_array_equal(got["step"], steps)
        # time: rerun keeps integer nanoseconds, so it is physics time rounded to 1 ns
        np.testing.assert_array_equal(got["time"], np.rint(rows[:, 0] * 1e9) / 1e9)
        np.testing.assert_allclose(got["time"], rows[:, 0], rtol=0, atol=0.5e-9)
        # float64 series come back bit for bit
        assert got["cube_height"][-1] == ep.physics[-1, CUBE_Z]
        np.testing.assert_array_equal(got["cube_height"], rows[:, CUBE_Z])
        np.testing.assert_array_equal(got["finger_opening"], rows[:, [4, 5]].mean(axis=1))
        for i, name in enumerate(("ctrl_x", "ctrl_y", "ctrl_z", "ctrl_gripper")):
            np.testing.assert_array_equal(got[name], ctrl[steps, i])
        np.testing.assert_array_equal(got["left_normal_force"], np.abs(ep.sensordata[steps, 2]))
        np.testing.assert_array_equal(got["right_normal_force"], np.abs(ep.sensordata[steps, 6]))
        # transforms are float32 in rerun
        cube_qpos = rows[:, 1 + 5 : 1 + 12]
        np.testing.assert_allclose(got["cube_position"], cube_qpos[:, :3], rtol=0, atol=1e-7)
        quat = cube_qpos[:, 3:] / np.linalg.norm(cube_qpos[:, 3:], axis=1, keepdims=True)
        np.testing.assert_allclose(got["cube_quat_wxyz"], quat, rtol=0, atol=1e-7)


def test_read_episode_missing_episode_is_a_key_error(condition_rrd: Path) -> None:
    with pytest.raises(KeyError, match="state 99"):
        read_episode(condition_rrd, condition=CONDITION, state_id=99)
    with pytest.raises(KeyError, match="'other'"):
        read_episode(condition_rrd, condition="other", state_id=0)


def test_missing_file_is_file_not_found(tmp_path: Path) -> None:
    with pytest.raises(FileNotFoundError):
        list_recordings(tmp_path / "none.rrd")


def _store(path: Path, recording_id: str):
    if path.is_dir():  # a condition's folder: the episode's own file
        path = path / f"{recording_id}.rrd"
    reader = rr.chunk.RrdReader(path)
    entry = next(e for e in reader.recordings() if e.recording_id == recording_id)
    return reader.store(store=entry)


def _static_batches(path: Path, recording_id: str) -> dict[str, object]:
    """{entity: record batch} of a recording's static chunks (one chunk per entity here)."""
    out = {}
    for chunk in _store(path, recording_id).stream():
        if chunk.is_static:
            assert chunk.entity_path not in out
            out[chunk.entity_path] = chunk.to_record_batch()
    return out


def _column(batch, name: str) -> list:
    return batch.column(batch.schema.names.index(name)).to_pylist()


def _rgba32(model: mujoco.MjModel, geom: str) -> int:
    rgba = np.rint(model.geom_rgba[model.geom(geom).id] * 255).astype(np.uint8)
    return int.from_bytes(bytes(rgba), "big")


def test_geometry_and_blueprint_are_in_every_recording(
    condition_rrd: Path, model: mujoco.MjModel
) -> None:
    # one static chunk per body with geoms, on the body's entity: no entity per geom
    expected = {
        "/world",
        "/world/carriage",
        "/world/carriage/left_finger",
        "/world/carriage/right_finger",
        "/world/cube",
    }
    for entry in list_recordings(condition_rrd):
        static = _static_batches(condition_rrd, entry["recording_id"])
        assert {e for e in static if e.startswith("/world")} == expected
        cube = static["/world/cube"]
        assert _column(cube, "Boxes3D:half_sizes") == [[pytest.approx([0.02] * 3, rel=1e-6)]]
        assert _column(cube, "Boxes3D:colors") == [[_rgba32(model, "cube")]]
        assert "Boxes3D:centers" not in cube.schema.names  # the cube's geom sits at its origin
        # the left finger's two boxes: instances posed in the finger's frame
        finger = static["/world/carriage/left_finger"]
        geoms = ["left_link", "left_pad"]
        [centers] = _column(finger, "Boxes3D:centers")
        np.testing.assert_allclose(centers, [model.geom(g).pos for g in geoms], rtol=1e-6)
        assert _column(finger, "Boxes3D:colors") == [[_rgba32(model, g) for g in geoms]]
        world = static["/world"]
        assert "ViewCoordinates:xyz" in world.schema.names
        assert _column(world, "Boxes3D:colors") == [[_rgba32(model, "floor")]]


def test_blueprint_draws_shapes_solid_and_plots_the_signals(condition_rrd: Path) -> None:
    reader = rr.chunk.RrdReader(condition_rrd / "blueprint.rbl")
    [blueprint] = reader.blueprints()
    assert blueprint.application_id == "mjtrial"  # so it applies to the episodes' recordings
    names, queries = set(), set()
    for chunk in reader.store(store=blueprint).stream():
        batch = chunk.to_record_batch()
        names.update(batch.schema.names)
        if "ViewContents:query" in batch.schema.names:
            queries.update(frozenset(q) for q in _column(batch, "ViewContents:query"))
    assert "Boxes3D:fill_mode" in names  # a default of the 3D view, not logged per shape
    assert {"+ /world/cube", "+ /world/carriage"} in queries  # cube height, opening, ctrl
    assert {"+ /world/carriage/left_finger", "+ /world/carriage/right_finger"} in queries


def test_signals_share_their_bodys_entity(condition_rrd: Path) -> None:
    static = _static_batches(condition_rrd, f"{CONDITION}-state-000000")
    names = {
        e: _column(b, "SeriesLines:names")[0]
        for e, b in static.items()
        if "SeriesLines:names" in b.schema.names
    }
    assert names == {
        "/world/cube": ["cube_height"],
        "/world/carriage": ["finger_opening", "ctrl_x", "ctrl_y", "ctrl_z", "ctrl_gripper"],
        "/world/carriage/left_finger": ["left_normal_force"],
        "/world/carriage/right_finger": ["right_normal_force"],
    }
    temporal = {
        chunk.entity_path: chunk.to_record_batch().schema.names
        for chunk in _store(condition_rrd, f"{CONDITION}-state-000000").stream()
        if not chunk.is_static
    }
    # one time-series chunk per moving body: its pose and its signals share row ids and times
    assert set(temporal) == set(names)
    for columns in temporal.values():
        assert {"Transform3D:translation", "Scalars:scalars", "sim_time"} <= set(columns)


def test_child_bodies_carry_their_pose_in_the_parent(
    condition_rrd: Path, model: mujoco.MjModel, ctrl: np.ndarray, episodes: list[EpisodeRecord]
) -> None:
    ep = episodes[0]
    steps = logged_steps(len(ctrl), 5)
    data = mujoco.MjData(model)
    xpos = []
    for row in ep.physics[steps]:  # the reference: MuJoCo's world poses
        data.qpos[:] = row[1 : 1 + model.nq]
        mujoco.mj_kinematics(model, data)
        xpos.append(data.xpos.copy())
    xpos = np.array(xpos)
    poses = {}
    for chunk in _store(condition_rrd, f"{CONDITION}-state-000000").stream():
        if not chunk.is_static:
            batch = chunk.to_record_batch()
            if "Transform3D:translation" in batch.schema.names:
                poses[chunk.entity_path] = np.concatenate(_column(batch, "Transform3D:translation"))
    assert set(poses) == {
        "/world/carriage",
        "/world/carriage/left_finger",
        "/world/carriage/right_finger",
        "/world/cube",
    }
    carriage, left = model.body("carriage").id, model.body("left_finger").id
    np.testing.assert_allclose(poses["/world/carriage"], xpos[:, carriage], atol=1e-7)
    relative = poses["/world/carriage/left_finger"]
    np.testing.assert_allclose(relative, xpos[:, left] - xpos[:, carriage], atol=1e-7)
    assert np.all(relative[:, [0, 2]] == 0.0)  # the finger slides along y only


def test_one_episode_file_holds_the_same_recording_and_the_blueprint(
    condition_rrd: Path, tmp_path: Path, model: mujoco.MjModel, ctrl: np.ndarray, episodes
) -> None:
    path = tmp_path / "ep.rrd"
    write_episode_recording(
        path,
        condition=CONDITION,
        episode=episodes[2],
        stamp=STAMP,
        spec=_spec(model, 5),
    )
    result = _verify(path)
    assert result.returncode == 0, result.stderr[-2000:]
    reader = rr.chunk.RrdReader(path)
    assert len(reader.blueprints()) == 1
    [recording] = list_recordings(path)
    assert recording == list_recordings(condition_rrd)[2]
    got = read_episode(path, condition=CONDITION, state_id=2)
    logged = read_episode(condition_rrd, condition=CONDITION, state_id=2)
    for key, value in logged.items():
        np.testing.assert_array_equal(got[key], value, err_msg=key)
    assert _leftovers(tmp_path) == []


def test_log_every_sets_the_number_of_rows(
    tmp_path: Path, model: mujoco.MjModel, ctrl: np.ndarray, episodes: list[EpisodeRecord]
) -> None:
    for log_every in (1, 10, 2000):
        path = tmp_path / f"every{log_every}"
        write_condition_recordings(
            path,
            condition=CONDITION,
            episodes=episodes[:1],
            stamp=STAMP,
            spec=_spec(model, log_every),
        )
        got = read_episode(path, condition=CONDITION, state_id=0)
        expected = logged_steps(len(ctrl), log_every)
        assert len(got["time"]) == len(expected) == {1: 1425, 10: 143, 2000: 1}[log_every]
        assert got["cube_height"][-1] == episodes[0].physics[-1, CUBE_Z]


# --------------------------------------------------------------------------------------------
# Failures
# --------------------------------------------------------------------------------------------


def test_failures_file_gathers_failed_episodes(condition_rrd: Path, tmp_path: Path) -> None:
    stamp = {"mjtrial_stamp": 1, "rule": "failures"}
    path = tmp_path / "failures.rrd"
    assert write_failures_rrd(path, [condition_rrd], stamp=stamp) == 1
    result = _verify(path)
    assert result.returncode == 0, result.stderr[-2000:]

    summary, copy = list_recordings(path)
    assert summary["recording_id"] == "failures"
    assert summary["n_failures"] == 1
    assert summary["sources"] == [condition_rrd.name]
    assert summary["provenance"] == stamp
    assert copy["recording_id"] == f"failures-{CONDITION}-state-000001"
    assert (copy["state_id"], copy["success"], copy["failure_category"]) == (1, False, "slipped")
    assert copy["provenance"] == stamp
    assert copy["source_provenance"] == STAMP
    assert read_rrd_stamp(path) == stamp

    original = read_episode(condition_rrd, condition=CONDITION, state_id=1)
    copied = read_episode(path, condition=CONDITION, state_id=1)
    for key, value in original.items():
        np.testing.assert_array_equal(copied[key], value, err_msg=key)
    assert len(rr.chunk.RrdReader(path).blueprints()) == 1


def test_failures_file_without_failures_is_still_stamped(
    tmp_path: Path, model: mujoco.MjModel, ctrl: np.ndarray, episodes: list[EpisodeRecord]
) -> None:
    source = tmp_path / "all_good"
    write_condition_recordings(
        source,
        condition="good",
        episodes=[episodes[0]],
        stamp=STAMP,
        spec=_spec(model, 50),
    )
    path = tmp_path / "failures.rrd"
    stamp = {"mjtrial_stamp": 1, "rule": "failures"}
    assert write_failures_rrd(path, [source], stamp=stamp) == 0
    assert [r["recording_id"] for r in list_recordings(path)] == ["failures"]
    assert read_stamp(path) == stamp


# --------------------------------------------------------------------------------------------
# Writing: errors, atomicity, home folder
# --------------------------------------------------------------------------------------------


def _leftovers(directory: Path) -> list[str]:
    return sorted(p.name for p in directory.iterdir() if p.name.startswith("."))


def test_failed_write_leaves_nothing(
    tmp_path: Path, model: mujoco.MjModel, ctrl: np.ndarray, episodes: list[EpisodeRecord]
) -> None:
    def broken():
        yield episodes[0]
        raise RuntimeError("rollout crashed")

    path = tmp_path / "c"
    with pytest.raises(RuntimeError, match="rollout crashed"):
        write_condition_recordings(
            path, condition="c", episodes=broken(), stamp=STAMP, spec=_spec(model, 5)
        )
    assert not path.exists()
    assert _leftovers(tmp_path) == []


@pytest.mark.parametrize(
    ("change", "match"),
    [
        ("stamp", "mjtrial_stamp"),
        ("log_every", "log_every"),
        ("ctrl", "ctrl"),
    ],
)
def test_invalid_arguments_raise(
    tmp_path: Path,
    model: mujoco.MjModel,
    episodes: list[EpisodeRecord],
    change: str,
    match: str,
) -> None:
    args = {
        "spec": _spec(model, 0 if change == "log_every" else 5),
        "condition": "c",
        "episodes": episodes[:1],
        "stamp": {"rule": "x"} if change == "stamp" else STAMP,
    }
    if change == "ctrl":
        args["episodes"] = [dataclasses.replace(episodes[0], ctrl=np.zeros((10, 3)))]
    with pytest.raises(ValueError, match=match):
        write_condition_recordings(tmp_path / "c", **args)
    assert not (tmp_path / "c").exists()
    assert _leftovers(tmp_path) == []


def test_a_shard_with_no_recorded_episode_is_a_folder_holding_its_blueprint(
    tmp_path: Path, model: mujoco.MjModel, ctrl: np.ndarray
) -> None:
    # recording.episodes: failed, and every episode of the shard succeeded
    path = tmp_path / "c"
    n = write_condition_recordings(
        path, condition="c", episodes=[], stamp=STAMP, spec=_spec(model, 5)
    )
    assert n == 0
    assert sorted(p.name for p in path.iterdir()) == ["blueprint.rbl", "recordings.json"]
    assert _leftovers(tmp_path) == []


def test_duplicate_and_misshapen_episodes_raise(
    tmp_path: Path, model: mujoco.MjModel, ctrl: np.ndarray, episodes: list[EpisodeRecord]
) -> None:
    common = {"spec": _spec(model, 5), "condition": "c", "stamp": STAMP}
    with pytest.raises(ValueError, match="twice"):
        write_condition_recordings(tmp_path / "c", episodes=[episodes[0]] * 2, **common)
    short = dataclasses.replace(
        episodes[0], physics=episodes[0].physics[:-1], sensordata=episodes[0].sensordata[:-1]
    )
    with pytest.raises(ValueError, match="physics"):
        write_condition_recordings(tmp_path / "c", episodes=[short], **common)
    assert not (tmp_path / "c").exists()


@pytest.mark.parametrize("group", [1, 2, 3])
def test_every_episode_is_written_whatever_the_group_size(
    tmp_path: Path,
    monkeypatch: pytest.MonkeyPatch,
    model: mujoco.MjModel,
    ctrl: np.ndarray,
    episodes: list[EpisodeRecord],
    group: int,
) -> None:
    monkeypatch.setattr(write_mod, "_GROUP", group)  # 3 episodes: full groups, and a remainder
    path = tmp_path / "c"
    n = write_condition_recordings(
        path, condition="c", episodes=episodes, stamp=STAMP, spec=_spec(model, 5)
    )
    assert n == 3
    assert [r["state_id"] for r in list_recordings(path)] == [0, 1, 2]
    for ep in episodes:
        got = read_episode(path, condition="c", state_id=ep.state_id)
        np.testing.assert_array_equal(
            got["cube_height"], ep.physics[logged_steps(len(ctrl), 5), CUBE_Z]
        )


def test_failures_without_a_path_to_the_pipe_go_through_a_scratch_file(
    condition_rrd: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setattr(route_mod, "_fd_path", lambda fd: None)  # as on Windows
    path = tmp_path / "failures.rrd"
    assert write_failures_rrd(path, [condition_rrd], stamp=STAMP) == 1
    result = _verify(path)
    assert result.returncode == 0, result.stderr[-2000:]
    assert len(list_recordings(path)) == 2
    assert _leftovers(tmp_path) == []


def test_shared_chunks_get_a_fresh_id_in_every_recording(condition_rrd: Path) -> None:
    ids = [
        chunk.id
        for entry in list_recordings(condition_rrd)
        for chunk in _store(condition_rrd, entry["recording_id"]).stream()
    ]
    assert len(ids) == len(set(ids))


def test_rewriting_a_folder_replaces_it_and_a_failed_rewrite_keeps_it(
    tmp_path: Path, model: mujoco.MjModel, ctrl: np.ndarray, episodes: list[EpisodeRecord]
) -> None:
    path = tmp_path / "c"
    common = {"spec": _spec(model, 50), "condition": "c", "stamp": STAMP}
    write_condition_recordings(path, episodes=episodes, **common)
    write_condition_recordings(path, episodes=episodes[:1], **common)
    assert sorted(p.name for p in path.iterdir()) == [
        "blueprint.rbl",
        "c-state-000000.rrd",
        "recordings.json",
    ]
    before = {p.name: p.read_bytes() for p in path.iterdir()}

    def broken():
        yield from episodes
        raise RuntimeError("rollout crashed")

    with pytest.raises(RuntimeError, match="rollout crashed"):
        write_condition_recordings(path, episodes=broken(), **common)
    assert {p.name: p.read_bytes() for p in path.iterdir()} == before
    assert _leftovers(tmp_path) == []


@pytest.mark.parametrize(
    "route",
    [
        "echo 'route: out of disk' >&2; exit 3",  # dies at once
        "head -c 100000 >/dev/null; echo 'route: out of disk' >&2; exit 3",  # midway
        "cat >/dev/null; echo 'route: out of disk' >&2; exit 3",  # at the end
    ],
)
def test_a_failing_route_raises_and_leaves_nothing(
    condition_rrd: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch, route: str
) -> None:
    fake = tmp_path / "fake-rerun"
    fake.write_text(f"#!/bin/sh\n{route}\n")
    fake.chmod(0o755)
    monkeypatch.setattr(route_mod, "rerun_cli", lambda: str(fake))
    out = tmp_path / "out"
    out.mkdir()
    with pytest.raises(RuntimeError, match="route (stopped early|failed).*out of disk"):
        write_failures_rrd(out / "failures.rrd", [condition_rrd], stamp=STAMP)
    assert list(out.iterdir()) == []


def test_writing_leaves_the_home_folder_alone(
    tmp_path: Path,
    monkeypatch: pytest.MonkeyPatch,
    model: mujoco.MjModel,
    ctrl: np.ndarray,
    episodes: list[EpisodeRecord],
) -> None:
    home = _fake_home(tmp_path)
    for name, value in home.items():
        monkeypatch.setenv(name, value)
    monkeypatch.delenv("CI", raising=False)  # the module must protect the home folder itself
    path = tmp_path / "out" / "c"
    write_condition_recordings(
        path,
        condition="c",
        episodes=episodes[:1],
        stamp=STAMP,
        spec=_spec(model, 50),
    )
    write_failures_rrd(tmp_path / "out" / "f.rrd", [path], stamp=STAMP)
    list_recordings(path)
    home_dir = Path(home["HOME"])
    assert not home_dir.exists() or list(home_dir.rglob("*")) == []


def test_a_recording_holds_one_time_series_chunk_per_moving_body(condition_rrd: Path) -> None:
    lines = _store(condition_rrd, f"{CONDITION}-state-000000").summary().splitlines()
    for entity in ("/world/cube", "/world/carriage/left_finger"):
        [series] = [line for line in lines if line.startswith(f"{entity} rows=285 static=False")]
        assert "Scalars:scalars" in series and "Transform3D:translation" in series
    static = [line for line in lines if line.startswith("/world/cube rows=1 static=True")]
    assert len(static) == 1  # its geometry and its series names, in one chunk
