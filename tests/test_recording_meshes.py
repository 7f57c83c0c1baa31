"""A model with meshes (gymnasium-robotics' Fetch): a condition's folder keeps the meshes once,
in its mesh store; each episode's file holds none, yet reads back whole from its path alone;
failures.rrd keeps one copy of them; sites are drawn. Episodes come from a plain mj_step loop."""

from __future__ import annotations

import shutil

import mujoco
import numpy as np
import pytest
from conftest import REPO_ROOT
from rerun.chunk import RrdReader

from mjtrial.recording import read_episode, write_condition_recordings, write_failures_rrd
from mjtrial.recording.names import MESH_STORE_FILE, body_entity
from mjtrial.recording.read import is_mesh_store, recording_chunks
from mjtrial.recording.series import Signal
from mjtrial.recording.write import EpisodeRecord, RecordingSpec
from mjtrial.sim.physics import FULLPHYSICS

FETCH = REPO_ROOT / "tasks" / "fetch_pick" / "assets" / "fetch" / "pick_and_place.xml"
N_STEPS, LOG_EVERY, N_EPISODES = 300, 5, 3
STAMP = {"mjtrial_stamp": 1, "rule": "test_recording_meshes"}
VERTICES = "Mesh3D:vertex_positions"


@pytest.fixture(scope="module")
def model() -> mujoco.MjModel:
    return mujoco.MjModel.from_xml_path(str(FETCH))


def _episode(model: mujoco.MjModel, seed: int) -> EpisodeRecord:
    """A plain mj_step loop: the mocap target wanders, the fingers get random ctrl."""
    data = mujoco.MjData(model)
    rng = np.random.default_rng(seed)
    nstate = mujoco.mj_stateSize(model, FULLPHYSICS)
    physics, ctrl = np.empty((N_STEPS, nstate)), np.empty((N_STEPS, model.nu))
    sensordata = np.empty((N_STEPS, model.nsensordata))
    for i in range(N_STEPS):
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


@pytest.fixture(scope="module")
def episodes(model) -> list[EpisodeRecord]:
    return [_episode(model, seed) for seed in range(N_EPISODES)]


@pytest.fixture(scope="module")
def folder(model, episodes, tmp_path_factory):
    gripper = model.body("robot0:gripper_link").id
    time = Signal("time", gripper, "time", lambda rows, sensors, ctrl: rows[:, 0])
    spec = RecordingSpec(
        model=model,
        signals=[time],
        state_names=["seed"],
        measure_names=[],
        n_steps=N_STEPS,
        log_every=LOG_EVERY,
    )
    out = tmp_path_factory.mktemp("fetch") / "c"
    written = write_condition_recordings(
        out, spec=spec, condition="c", episodes=episodes, stamp=STAMP
    )
    assert written == N_EPISODES
    return out


def _components(path) -> set[str]:
    reader = RrdReader(path)
    return {
        name
        for entry in reader.recordings()
        for chunk in reader.store(store=entry).stream()
        for name in chunk.to_record_batch().schema.names
    }


def _meshes(chunks) -> dict[str, np.ndarray]:
    """{entity: (n, 3) vertex positions} of the Mesh3D chunks."""
    out = {}
    for chunk in chunks:
        batch = chunk.to_record_batch()
        if VERTICES in batch.schema.names:
            [rows] = batch.column(batch.schema.names.index(VERTICES)).to_pylist()
            out[chunk.entity_path.lstrip("/")] = np.array(rows)
    return out


def _expected_meshes(model: mujoco.MjModel) -> dict[str, np.ndarray]:
    """Each body's visible mesh vertices in the body frame, straight from MuJoCo's arrays."""
    out: dict[str, list[np.ndarray]] = {}
    for g in range(model.ngeom):
        if model.geom_type[g] != mujoco.mjtGeom.mjGEOM_MESH or model.geom_group[g] > 2:
            continue
        mesh = model.geom_dataid[g]
        start, n = model.mesh_vertadr[mesh], model.mesh_vertnum[mesh]
        rotation = np.empty(9)
        mujoco.mju_quat2Mat(rotation, model.geom_quat[g])
        vertices = model.mesh_vert[start : start + n] @ rotation.reshape(3, 3).T
        out.setdefault(body_entity(model, model.geom_bodyid[g]), []).append(
            vertices + model.geom_pos[g]
        )
    return {entity: np.concatenate(parts) for entity, parts in out.items()}


def test_episode_files_hold_no_mesh_and_the_folder_holds_them_once(model, folder):
    files = sorted(folder.glob("c-state-*.rrd"))
    assert len(files) == N_EPISODES
    for file in files:
        assert VERTICES not in _components(file)
    store = RrdReader(folder / MESH_STORE_FILE)
    [entry] = store.recordings()
    assert is_mesh_store(entry)
    meshes = _meshes(store.store(store=entry).stream())
    expected = _expected_meshes(model)
    assert sorted(meshes) == sorted(expected)
    assert sum(len(v) for v in meshes.values()) == sum(
        model.mesh_vertnum[model.geom_dataid[g]]
        for g in range(model.ngeom)
        if model.geom_type[g] == mujoco.mjtGeom.mjGEOM_MESH and model.geom_group[g] <= 2
    )


def test_an_episode_file_alone_reads_back_with_its_meshes(model, folder, tmp_path):
    # the file and its folder's mesh store, nothing else (the other episodes are not there)
    shutil.copy(folder / "c-state-000001.rrd", tmp_path)
    shutil.copy(folder / MESH_STORE_FILE, tmp_path)
    path = tmp_path / "c-state-000001.rrd"
    reader = RrdReader(path)
    [entry] = reader.recordings()
    meshes = _meshes(recording_chunks(reader, entry, path))
    expected = _expected_meshes(model)
    assert sorted(meshes) == sorted(expected)
    for entity, vertices in expected.items():
        np.testing.assert_allclose(meshes[entity], vertices, atol=1e-6)  # float32 in rerun

    # a fixed body that holds only meshes (the e-stop): its pose travels with its meshes
    estop = model.body("robot0:estop_link").id
    entity = "/" + body_entity(model, estop)
    assert not [c for c in reader.store(store=entry).stream() if c.entity_path == entity]
    [pose] = [
        c.to_record_batch()
        for c in recording_chunks(reader, entry, path)
        if c.entity_path == entity and "Transform3D:translation" in c.to_record_batch().schema.names
    ]
    [[translation]] = pose.column(pose.schema.names.index("Transform3D:translation")).to_pylist()
    assert translation == pytest.approx(model.body_pos[estop].tolist(), abs=1e-7)

    (tmp_path / MESH_STORE_FILE).unlink()
    with pytest.raises(FileNotFoundError, match=r"c-state-000001\.rrd: its meshes are in mesh"):
        recording_chunks(reader, entry, path)


def test_read_episode_takes_a_one_episode_file_alone(model, folder, episodes):
    path = folder / "c-state-000002.rrd"
    alone = read_episode(path)
    named = read_episode(path, condition="c", state_id=2)
    assert sorted(alone) == sorted(named)
    for key in alone:
        np.testing.assert_array_equal(alone[key], named[key])
    # the object's free joint, as the physics rows have it at the logged steps
    steps = np.arange(LOG_EVERY - 1, N_STEPS, LOG_EVERY)
    np.testing.assert_array_equal(alone["step"], steps)
    adr = model.jnt_qposadr[model.joint("object0:joint").id]
    qpos = episodes[2].physics[steps, 1 : 1 + model.nq]
    np.testing.assert_allclose(alone["object0_position"], qpos[:, adr : adr + 3], atol=1e-6)
    np.testing.assert_allclose(alone["time"], episodes[2].physics[steps, 0], atol=1e-9)

    with pytest.raises(ValueError, match="a folder: give condition and state_id"):
        read_episode(folder)
    with pytest.raises(ValueError, match="give both condition and state_id"):
        read_episode(path, condition="c")


def test_sites_are_drawn(model, folder):
    """target0 (a red sphere of radius 2 cm at 0.5 m above floor0's origin) is drawn on its
    body; the invisible grip site (alpha 0) is not."""
    reader = RrdReader(folder / "c-state-000000.rrd")
    [entry] = reader.recordings()
    site = model.site("target0").id
    entity = "/" + body_entity(model, model.site_bodyid[site])
    [batch] = [
        c.to_record_batch()
        for c in reader.store(store=entry).stream()
        if c.entity_path == entity and c.is_static
    ]
    names = batch.schema.names
    [centers] = batch.column(names.index("Ellipsoids3D:centers")).to_pylist()
    [half_sizes] = batch.column(names.index("Ellipsoids3D:half_sizes")).to_pylist()
    [colors] = batch.column(names.index("Ellipsoids3D:colors")).to_pylist()
    assert centers == [pytest.approx(model.site_pos[site].tolist())]
    assert half_sizes == [pytest.approx([0.02] * 3)]
    assert colors == [0xFF0000FF]  # rgba 1 0 0 1, packed as rerun's u32 RGBA
    grip = model.site("robot0:grip").id
    assert model.site_rgba[grip][3] == 0
    grip_entity = "/" + body_entity(model, model.site_bodyid[grip])
    for chunk in reader.store(store=entry).stream():
        if chunk.entity_path == grip_entity:
            assert not any("Ellipsoids3D" in n for n in chunk.to_record_batch().schema.names)


def test_failures_rrd_holds_the_meshes_once_and_each_failure_reads_them(model, folder, tmp_path):
    path = tmp_path / "failures.rrd"
    assert write_failures_rrd(path, [folder], stamp=STAMP) == N_EPISODES
    reader = RrdReader(path)
    entries = reader.recordings()
    stores = [e for e in entries if is_mesh_store(e)]
    assert len(stores) == 1
    copies = [e for e in entries if e.recording_id.startswith("failures-c-state-")]
    assert len(copies) == N_EPISODES
    expected = _expected_meshes(model)
    for entry in copies:
        chunks = list(reader.store(store=entry).stream())
        assert not _meshes(chunks)
        meshes = _meshes(recording_chunks(reader, entry, path))
        assert sorted(meshes) == sorted(expected)
    episode = read_episode(path, condition="c", state_id=1)
    assert len(episode["step"]) == N_STEPS // LOG_EVERY


def test_a_whole_episode_file_holds_its_meshes(model, folder, tmp_path):
    from mjtrial.recording import write_whole_episode

    output = tmp_path / "whole.rrd"
    rid = write_whole_episode(folder / "c-state-000000.rrd", output)
    assert rid == "c-state-000000"
    reader = RrdReader(output)
    [entry] = reader.recordings()
    meshes = _meshes(reader.store(store=entry).stream())
    expected = _expected_meshes(model)
    assert sorted(meshes) == sorted(expected)
    np.testing.assert_array_equal(
        read_episode(output)["time"], read_episode(folder / "c-state-000000.rrd")["time"]
    )


def test_mjtrial_view_writes_an_episode_of_failures_rrd_whole(model, folder, tmp_path, capsys):
    from mjtrial.cli import main

    failures = tmp_path / "failures.rrd"
    write_failures_rrd(failures, [folder], stamp=STAMP)
    output = tmp_path / "ep.rrd"
    argv = ["view", str(failures), "--condition", "c", "--state", "2", "--output", str(output)]
    assert main([*argv, "--no-viewer"]) == 0
    assert "failures-c-state-000002, with its meshes" in capsys.readouterr().out
    reader = RrdReader(output)
    [entry] = reader.recordings()
    assert sorted(_meshes(reader.store(store=entry).stream())) == sorted(_expected_meshes(model))
    # an existing output is kept; a file of several episodes needs the episode named
    assert main([*argv, "--no-viewer"]) == 2
    assert "exists (pass --force" in capsys.readouterr().err
    assert main(["view", str(failures), "--output", str(tmp_path / "x.rrd"), "--no-viewer"]) == 1
    assert "give condition and state_id" in capsys.readouterr().err


def test_resimulated_episodes_in_one_file_share_one_mesh_store(model, episodes, tmp_path):
    from mjtrial.recording.failures import write_episodes_rrd
    from mjtrial.recording.write import EpisodeStores

    gripper = model.body("robot0:gripper_link").id
    time = Signal("time", gripper, "time", lambda rows, sensors, ctrl: rows[:, 0])
    spec = RecordingSpec(
        model=model,
        signals=[time],
        state_names=["seed"],
        measure_names=[],
        n_steps=N_STEPS,
        log_every=LOG_EVERY,
    )
    groups = [
        (EpisodeStores(spec, condition=c, stamp=STAMP, share_meshes=True), episodes[:2])
        for c in ("a", "b")
    ]
    path = tmp_path / "calls.rrd"
    n = write_episodes_rrd(
        path, groups, summary_id="calls", prefix="calls-", title="t", table="|", stamp=STAMP
    )
    assert n == 4
    reader = RrdReader(path)
    entries = reader.recordings()
    assert sum(is_mesh_store(e) for e in entries) == 1
    [entry] = [e for e in entries if e.recording_id == "calls-b-state-000001"]
    assert not _meshes(reader.store(store=entry).stream())
    assert sorted(_meshes(recording_chunks(reader, entry, path))) == sorted(_expected_meshes(model))


def _cut(path, fraction=2 / 3) -> None:
    data = path.read_bytes()
    path.write_bytes(data[: int(len(data) * fraction)])


@pytest.mark.parametrize("damaged", ["c-state-000000.rrd", MESH_STORE_FILE])
def test_a_truncated_episode_or_mesh_store_is_one_line_naming_it(folder, tmp_path, capsys, damaged):
    """Issue 42 item 14: `mjtrial view` and `read_episode` on a folder where the episode's
    file or the mesh store was cut short: one line naming the file and the command that
    rebuilds the folder, not a traceback."""
    from mjtrial.cli import main
    from mjtrial.replay import read_episode as read_any

    copy = tmp_path / "c"
    shutil.copytree(folder, copy)
    _cut(copy / damaged)
    expected = (
        f"{copy / damaged}: not a readable .rrd file (truncated or damaged: Failed to decode "
        "frame: "
    )
    hint = f"; `snakemake -c2 -R {copy}` rebuilds its folder and what was made from it"
    argv = ["view", str(copy / "c-state-000000.rrd"), "--output", str(tmp_path / "ep.rrd")]
    assert main([*argv, "--no-viewer"]) == 1
    err = capsys.readouterr().err
    assert err.startswith(f"mjtrial view: {expected}") and err.endswith(hint + "\n"), err
    assert err.count("\n") == 1
    if damaged != MESH_STORE_FILE:  # an episode's series need no meshes
        with pytest.raises(ValueError) as caught:
            read_any(copy / damaged)
        assert str(caught.value).startswith(expected) and str(caught.value).endswith(hint)


def test_a_deleted_mesh_store_is_named_with_the_command_that_rebuilds_it(folder, tmp_path, capsys):
    """Issue 42 item 14: the folder is the output Snakemake sees, so a deleted meshes.rrd is
    'Nothing to be done'; the folder's record names what is missing and how to rebuild it."""
    from mjtrial.cli import main
    from mjtrial.provenance.recording_folders import folder_problem

    copy = tmp_path / "c"
    shutil.copytree(folder, copy)
    assert folder_problem(copy) is None
    (copy / MESH_STORE_FILE).unlink()
    (copy / "c-state-000001.rrd").unlink()
    hint = f"`snakemake -c2 -R {copy}` rebuilds its folder and what was made from it"
    assert folder_problem(copy) == (
        f"{copy}: its mesh store meshes.rrd and 1 of its 3 episodes' recordings missing "
        f"(recordings.json records them); {hint}"
    )
    argv = ["view", str(copy / "c-state-000000.rrd"), "--output", str(tmp_path / "ep.rrd")]
    assert main([*argv, "--no-viewer"]) == 1
    assert (
        capsys.readouterr()
        .err.strip()
        .endswith(f"(copy that file beside it, or open the episode with its folder); {hint}")
    )


def test_view_counts_a_file_s_episodes_alike_in_every_message(folder, tmp_path, capsys):
    """Issue 42 item 15: failures.rrd of 3 episodes (after its summary, with a mesh store) was
    said to hold 4 recordings by one message and 5 by another; both now count its episodes."""
    from mjtrial.cli import main

    failures = tmp_path / "failures.rrd"
    write_failures_rrd(failures, [folder], stamp=STAMP)
    assert len(RrdReader(failures).recordings()) == N_EPISODES + 2  # summary, mesh store
    output = str(tmp_path / "x.rrd")
    assert main(["view", str(failures), "--output", output, "--no-viewer"]) == 1
    assert f"holds {N_EPISODES} episodes' recordings, expected one;" in capsys.readouterr().err
    argv = ["view", str(failures), "--condition", "c", "--state", "9", "--output", output]
    assert main([*argv, "--no-viewer"]) == 1
    assert capsys.readouterr().err.rstrip().endswith(f"among its {N_EPISODES} episodes' recordings")


def test_an_episode_file_short_of_its_last_byte_is_one_line(folder, tmp_path, capsys):
    """Cut inside its footer, rerun reads the file by a whole-file scan (with a warning) and
    cannot give its store: one line, as for a frame cut short."""
    from mjtrial.cli import main

    copy = tmp_path / "c"
    shutil.copytree(folder, copy)
    episode = copy / "c-state-000000.rrd"
    episode.write_bytes(episode.read_bytes()[:-1])
    argv = ["view", str(episode), "--output", str(tmp_path / "ep.rrd"), "--no-viewer"]
    assert main(argv) == 1
    assert capsys.readouterr().err == (
        f"mjtrial view: {episode}: not a readable .rrd file (truncated or damaged: it has no "
        f"footer, which every file written whole has); `snakemake -c2 -R {copy}` rebuilds its "
        "folder and what was made from it\n"
    )
