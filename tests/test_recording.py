"""Tests for mjtrial.recording: rerun recordings of episodes, written and read back."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import mujoco
import numpy as np
import pytest
import rerun as rr

from mjtrial import model_path
from mjtrial import recording as rec_mod
from mjtrial.protocol import control_sequence
from mjtrial.provenance import read_stamp
from mjtrial.recording import (
    EpisodeRecord,
    body_poses,
    list_recordings,
    log_episode,
    log_model_geometry,
    logged_steps,
    mujoco_to_rerun_quat,
    read_episode,
    read_rrd_stamp,
    rerun_to_mujoco_quat,
    write_condition_recordings,
    write_failures_rrd,
)
from mjtrial.simulate import InitialState, iter_episode_batches, load_model

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
    return str(cli) if cli.exists() else rec_mod._rerun_cli()


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


@pytest.fixture(scope="module")
def episodes(model: mujoco.MjModel) -> list[EpisodeRecord]:
    out = []
    for batch in iter_episode_batches(model, STATES, lift_time=LIFT_TIME, nthread=1):
        for state, physics, sensordata in zip(
            batch.states, batch.physics, batch.sensordata, strict=True
        ):
            failed = state.state_id == 1  # outcome labels are the caller's business
            out.append(
                EpisodeRecord(
                    state=state,
                    physics=physics,
                    sensordata=sensordata,
                    success=not failed,
                    final_height=float(physics[-1, CUBE_Z]),
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
    path = tmp_path_factory.mktemp("rrd") / f"{CONDITION}.rrd"
    mp = pytest.MonkeyPatch()  # module scope: the autouse fixture has not run yet
    for name, value in _fake_home(tmp_path_factory.getbasetemp()).items():
        mp.setenv(name, value)
    try:
        n = write_condition_recordings(
            path,
            model=model,
            condition=CONDITION,
            episodes=iter(episodes),  # a one-pass iterable, as the pipeline passes
            ctrl=ctrl,
            stamp=STAMP,
            log_every=5,
        )
    finally:
        mp.undo()
    assert n == len(episodes)
    return path


# --------------------------------------------------------------------------------------------
# Quaternions and kinematics
# --------------------------------------------------------------------------------------------


def test_quaternion_90_degrees_about_z() -> None:
    c = s = np.sqrt(0.5)
    np.testing.assert_array_equal(mujoco_to_rerun_quat(np.array([c, 0, 0, s])), [0, 0, s, c])
    np.testing.assert_array_equal(rerun_to_mujoco_quat(np.array([0, 0, s, c])), [c, 0, 0, s])


def test_quaternion_matches_mujoco_rotation() -> None:
    # the converted quaternion rotates x onto y, as MuJoCo's does
    q = np.empty(4)
    mujoco.mju_axisAngle2Quat(q, np.array([0.0, 0.0, 1.0]), np.pi / 2)
    x, y, z, w = mujoco_to_rerun_quat(q)
    v = np.array([1.0, 0.0, 0.0])
    u = np.array([x, y, z])
    rotated = v + 2 * w * np.cross(u, v) + 2 * np.cross(u, np.cross(u, v))
    np.testing.assert_allclose(rotated, [0.0, 1.0, 0.0], atol=1e-15)


def test_quaternion_round_trip_vectorised() -> None:
    q = np.random.default_rng(0).normal(size=(5, 7, 4))
    xyzw = mujoco_to_rerun_quat(q)
    assert xyzw.shape == q.shape
    np.testing.assert_array_equal(xyzw[..., 3], q[..., 0])
    np.testing.assert_array_equal(rerun_to_mujoco_quat(xyzw), q)
    with pytest.raises(ValueError, match=r"\(\.\.\., 4\)"):
        mujoco_to_rerun_quat(np.zeros((3, 3)))


def _mj_kinematics(model: mujoco.MjModel, qpos: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    data = mujoco.MjData(model)
    xpos, xquat = [], []
    for row in qpos:
        data.qpos[:] = row
        mujoco.mj_kinematics(model, data)
        xpos.append(data.xpos.copy())
        xquat.append(data.xquat.copy())
    return np.array(xpos), np.array(xquat)


def test_body_poses_match_mj_kinematics_on_episode(
    model: mujoco.MjModel, episodes: list[EpisodeRecord]
) -> None:
    physics = episodes[1].physics
    qpos = physics[[0, 400, 800, 1100, len(physics) - 1], 1 : 1 + model.nq]
    xpos, xquat = body_poses(model, qpos)
    ref_pos, ref_quat = _mj_kinematics(model, qpos)
    np.testing.assert_allclose(xpos, ref_pos, rtol=0, atol=1e-14)
    np.testing.assert_allclose(xquat, ref_quat, rtol=0, atol=1e-14)


ARTICULATED = """
<mujoco>
  <worldbody>
    <body name="base" pos="0.1 0.2 0.3" quat="0.9 0.1 0.3 0.2">
      <joint name="slide" type="slide" axis="1 1 0" ref="0.05"/>
      <geom type="sphere" size="0.05"/>
      <body name="arm" pos="0 0.1 0" euler="0.3 0 0.5">
        <joint name="hinge" type="hinge" axis="0 1 1" pos="0.02 0 0.01" ref="0.4"/>
        <geom type="capsule" size="0.01 0.05"/>
        <body name="wrist" pos="0.1 0 0">
          <joint name="ball" type="ball" pos="0 0.01 0"/>
          <joint name="slide2" type="slide" axis="0 0 1"/>
          <geom type="box" size="0.01 0.02 0.03"/>
        </body>
      </body>
    </body>
    <body name="free" pos="1 0 0">
      <freejoint/>
      <geom type="box" size="0.1 0.1 0.1"/>
    </body>
  </worldbody>
</mujoco>
"""


def test_body_poses_match_mj_kinematics_for_all_joint_types() -> None:
    model = mujoco.MjModel.from_xml_string(ARTICULATED)
    rng = np.random.default_rng(1)
    qpos = rng.normal(size=(6, model.nq))  # quaternions unnormalised on purpose
    xpos, xquat = body_poses(model, qpos)
    ref_pos, ref_quat = _mj_kinematics(model, qpos)
    np.testing.assert_allclose(xpos, ref_pos, rtol=0, atol=1e-12)
    np.testing.assert_allclose(xquat, ref_quat, rtol=0, atol=1e-12)


def test_body_poses_rejects_wrong_width(model: mujoco.MjModel) -> None:
    with pytest.raises(ValueError, match="qpos"):
        body_poses(model, np.zeros((2, model.nq + 1)))


def test_logged_steps() -> None:
    np.testing.assert_array_equal(logged_steps(4, 1), [0, 1, 2, 3])
    np.testing.assert_array_equal(logged_steps(10, 5), [4, 9])
    np.testing.assert_array_equal(logged_steps(12, 5), [4, 9, 11])  # the last step always
    np.testing.assert_array_equal(logged_steps(3, 5), [2])
    assert len(logged_steps(1425, 5)) == 285
    with pytest.raises(ValueError, match="log_every"):
        logged_steps(10, 0)
    with pytest.raises(TypeError, match="log_every"):
        logged_steps(10, 2.0)  # type: ignore[arg-type]


# --------------------------------------------------------------------------------------------
# A condition file
# --------------------------------------------------------------------------------------------


def test_condition_file_passes_rerun_verify(condition_rrd: Path) -> None:
    result = _verify(condition_rrd)
    assert result.returncode == 0, result.stderr[-2000:]


def test_list_recordings_gives_every_episode_with_its_properties(
    condition_rrd: Path, ctrl: np.ndarray, episodes: list[EpisodeRecord]
) -> None:
    recordings = list_recordings(condition_rrd)
    assert [r["recording_id"] for r in recordings] == [
        f"{CONDITION}-state-{s.state_id:06d}" for s in STATES
    ]
    for r, ep in zip(recordings, episodes, strict=True):
        s = ep.state
        assert r["application_id"] == "mjtrial"
        assert r["name"] == f"{CONDITION} / state {s.state_id}"
        assert r["condition"] == CONDITION
        assert r["state_id"] == s.state_id
        assert (r["dx"], r["dy"], r["yaw"], r["mass"]) == (s.dx, s.dy, s.yaw, s.mass)
        assert r["success"] is ep.success
        assert r["final_height"] == ep.final_height
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
        got = read_episode(condition_rrd, condition=CONDITION, state_id=ep.state.state_id)
        steps = logged_steps(len(ctrl), 5)
        rows = ep.physics[steps]
        n = len(steps)
        assert {k: v.shape for k, v in got.items()} == {
            "time": (n,),
            "step": (n,),
            "cube_position": (n, 3),
            "cube_quat_wxyz": (n, 4),
            "finger_opening": (n,),
            "ctrl": (n, 4),
            "cube_height": (n,),
            "contact_force": (n, 2),
        }
        np.testing.assert_array_equal(got["step"], steps)
        # time: rerun keeps integer nanoseconds, so it is physics time rounded to 1 ns
        np.testing.assert_array_equal(got["time"], np.rint(rows[:, 0] * 1e9) / 1e9)
        np.testing.assert_allclose(got["time"], rows[:, 0], rtol=0, atol=0.5e-9)
        # float64 series come back bit for bit
        assert got["cube_height"][-1] == ep.physics[-1, CUBE_Z]
        np.testing.assert_array_equal(got["cube_height"], rows[:, CUBE_Z])
        np.testing.assert_array_equal(got["finger_opening"], rows[:, [4, 5]].mean(axis=1))
        np.testing.assert_array_equal(got["ctrl"], ctrl[steps])
        np.testing.assert_array_equal(got["contact_force"], np.abs(ep.sensordata[steps][:, [2, 6]]))
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
    reader = rr.chunk.RrdReader(path)
    entry = next(e for e in reader.recordings() if e.recording_id == recording_id)
    return reader.store(store=entry)


def test_geometry_and_blueprint_are_in_every_recording(
    condition_rrd: Path, model: mujoco.MjModel
) -> None:
    reader = rr.chunk.RrdReader(condition_rrd)
    assert len(reader.blueprints()) == 1
    expected = {
        "/world",
        "/world/world/floor",
        "/world/carriage/carriage_block",
        "/world/left_finger/left_link",
        "/world/left_finger/left_pad",
        "/world/right_finger/right_link",
        "/world/right_finger/right_pad",
        "/world/cube/cube",
    }
    for entry in reader.recordings():
        static = {}
        for chunk in reader.store(store=entry).stream().filter(content="/world/**"):
            if chunk.is_static:
                static[chunk.entity_path] = chunk.to_record_batch()
        assert set(static) == expected
        cube = static["/world/cube/cube"]
        half = cube.column(cube.schema.names.index("Boxes3D:half_sizes"))
        np.testing.assert_allclose(half.flatten().flatten().to_numpy(), [0.02] * 3, rtol=1e-7)
        colors = cube.column(cube.schema.names.index("Boxes3D:colors")).flatten().to_numpy()
        rgba = np.rint(model.geom_rgba[model.geom("cube").id] * 255).astype(np.uint32)
        assert colors[0] == int.from_bytes(bytes(rgba.astype(np.uint8)), "big")


def test_log_every_sets_the_number_of_rows(
    tmp_path: Path, model: mujoco.MjModel, ctrl: np.ndarray, episodes: list[EpisodeRecord]
) -> None:
    for log_every in (1, 10, 2000):
        path = tmp_path / f"every{log_every}.rrd"
        write_condition_recordings(
            path,
            model=model,
            condition=CONDITION,
            episodes=episodes[:1],
            ctrl=ctrl,
            stamp=STAMP,
            log_every=log_every,
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
    source = tmp_path / "all_good.rrd"
    write_condition_recordings(
        source,
        model=model,
        condition="good",
        episodes=[episodes[0]],
        ctrl=ctrl,
        stamp=STAMP,
        log_every=50,
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

    path = tmp_path / "c.rrd"
    with pytest.raises(RuntimeError, match="rollout crashed"):
        write_condition_recordings(
            path, model=model, condition="c", episodes=broken(), ctrl=ctrl, stamp=STAMP, log_every=5
        )
    assert not path.exists()
    assert _leftovers(tmp_path) == []


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        ({"episodes": []}, "no episodes"),
        ({"stamp": {"rule": "x"}}, "mjtrial_stamp"),
        ({"log_every": 0}, "log_every"),
        ({"ctrl": np.zeros((10, 3))}, "ctrl"),
    ],
)
def test_invalid_arguments_raise(
    tmp_path: Path,
    model: mujoco.MjModel,
    ctrl: np.ndarray,
    episodes: list[EpisodeRecord],
    kwargs: dict,
    match: str,
) -> None:
    args = {
        "model": model,
        "condition": "c",
        "episodes": episodes[:1],
        "ctrl": ctrl,
        "stamp": STAMP,
        "log_every": 5,
        **kwargs,
    }
    with pytest.raises(ValueError, match=match):
        write_condition_recordings(tmp_path / "c.rrd", **args)
    assert not (tmp_path / "c.rrd").exists()
    assert _leftovers(tmp_path) == []


def test_duplicate_and_misshapen_episodes_raise(
    tmp_path: Path, model: mujoco.MjModel, ctrl: np.ndarray, episodes: list[EpisodeRecord]
) -> None:
    common = {"model": model, "condition": "c", "ctrl": ctrl, "stamp": STAMP, "log_every": 5}
    with pytest.raises(ValueError, match="twice"):
        write_condition_recordings(tmp_path / "c.rrd", episodes=[episodes[0]] * 2, **common)
    short = EpisodeRecord(
        STATES[0], episodes[0].physics[:-1], episodes[0].sensordata[:-1], True, 0.3
    )
    with pytest.raises(ValueError, match="physics"):
        write_condition_recordings(tmp_path / "c.rrd", episodes=[short], **common)
    assert not (tmp_path / "c.rrd").exists()


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
    path = tmp_path / "out" / "c.rrd"
    write_condition_recordings(
        path,
        model=model,
        condition="c",
        episodes=episodes[:1],
        ctrl=ctrl,
        stamp=STAMP,
        log_every=50,
    )
    write_failures_rrd(tmp_path / "out" / "f.rrd", [path], stamp=STAMP)
    list_recordings(path)
    home_dir = Path(home["HOME"])
    assert not home_dir.exists() or list(home_dir.rglob("*")) == []


# --------------------------------------------------------------------------------------------
# Logging to a live recording
# --------------------------------------------------------------------------------------------


def test_live_logging_writes_the_same_layout(
    tmp_path: Path, model: mujoco.MjModel, ctrl: np.ndarray, episodes: list[EpisodeRecord]
) -> None:
    path = tmp_path / "live.rrd"
    rec = rr.RecordingStream("mjtrial", recording_id="live", send_properties=False)
    rec.save(path)
    log_model_geometry(rec, model)
    ep = episodes[0]
    log_episode(rec, model, physics=ep.physics, sensordata=ep.sensordata, ctrl=ctrl, log_every=5)
    rec.disconnect()
    summary = _store(path, "live").summary()
    assert "/world/cube rows=285 static=False" in summary
    assert "/plots/ctrl rows=285 static=False" in summary
    assert "/world/cube/cube rows=1 static=True" in summary


PRIMITIVES = """
<mujoco>
  <asset>
    <material name="red" rgba="1 0 0 1"/>
    <mesh name="tet" vertex="0 0 0  1 0 0  0 1 0  0 0 1"/>
  </asset>
  <worldbody>
    <geom name="ground" type="plane" size="0 0 1" material="red"/>
    <body name="b">
      <freejoint/>
      <geom name="ball" type="sphere" size="0.1" material="red" rgba="0 1 0 1"/>
      <geom type="capsule" size="0.05 0.2" pos="0 0 1" euler="1 0 0"/>
      <geom type="cylinder" size="0.05 0.2"/>
      <geom type="ellipsoid" size="0.1 0.2 0.3"/>
      <geom type="mesh" mesh="tet"/>
      <geom name="hidden" type="box" size="1 1 1" group="3"/>
    </body>
  </worldbody>
</mujoco>
"""


def test_every_primitive_type_is_drawn(tmp_path: Path) -> None:
    model = mujoco.MjModel.from_xml_string(PRIMITIVES)
    path = tmp_path / "shapes.rrd"
    rec = rr.RecordingStream("mjtrial", recording_id="shapes", send_properties=False)
    rec.save(path)
    log_model_geometry(rec, model)
    rec.disconnect()
    summary = _store(path, "shapes").summary()
    lines = {line.split()[0]: line for line in summary.splitlines()}
    assert "Boxes3D:half_sizes" in lines["/world/world/ground"]  # plane: a flat box
    assert "Ellipsoids3D:half_sizes" in lines["/world/b/ball"]
    assert "Capsules3D:lengths" in lines["/world/b/geom_2"]
    assert "Cylinders3D:lengths" in lines["/world/b/geom_3"]
    assert "Ellipsoids3D:half_sizes" in lines["/world/b/geom_4"]
    assert "Mesh3D:triangle_indices" in lines["/world/b/geom_5"]
    assert "/world/b/hidden" not in lines  # group 3 is not drawn

    reader = rr.chunk.RrdReader(path)
    store = reader.store(store=reader.recordings()[0])
    colors = {}
    for chunk in store.stream().filter(content=["/world/world/ground", "/world/b/ball"]):
        batch = chunk.to_record_batch()
        name = next(n for n in batch.schema.names if n.endswith(":colors"))
        colors[chunk.entity_path] = batch.column(batch.schema.names.index(name)).flatten()[0]
    assert colors["/world/world/ground"].as_py() == 0xFF0000FF  # the material's colour
    assert colors["/world/b/ball"].as_py() == 0x00FF00FF  # the geom's own rgba wins
