"""The built-in experiment on gymnasium-robotics' Fetch, as shipped: the files are the wheel's, the
compiled model has exactly the joints the shipped XML declares (no stand-in joints), an episode
starts where the suite's own reset leaves it (written out here from fetch_env.py), every drawn
block obeys the suite's redraw rule, and a small run through the whole pipeline verifies, replays
and reports what drives the arm."""

from __future__ import annotations

import hashlib
import re
import xml.etree.ElementTree as ET
from pathlib import Path

import mujoco
import numpy as np
import pyarrow.parquet as pq
import pytest
import yaml
from conftest import REPO_ROOT, copy_workflow, run_snakemake

from mjtrial.cli import main
from mjtrial.sim.physics import FULLPHYSICS, load_model
from mjtrial.task import BoundTask, load_task

pytestmark = pytest.mark.end_to_end

FOLDER = REPO_ROOT / "tasks" / "fetch_pick"
CONFIG = "config/fetch_small.yaml"
RESULTS = "results/fetch_small"


def test_the_files_are_the_ones_the_wheel_ships():
    """Each row of the README's table (the wheel's sha256 of each file) holds, and every file
    under assets/ is in the table."""
    rows = re.findall(
        r"^\| `([^`]+)` \| `([0-9a-f]{64})` \|$", (FOLDER / "README.md").read_text(), re.M
    )
    assert {name for name, _ in rows} == {
        str(p.relative_to(FOLDER / "assets")) for p in (FOLDER / "assets").rglob("*") if p.is_file()
    }
    for name, sha256 in rows:
        assert hashlib.sha256((FOLDER / "assets" / name).read_bytes()).hexdigest() == sha256, name


def test_the_compiled_model_has_exactly_the_shipped_joints_and_actuators():
    """No fake joints: the joints and actuators are those the shipped XML files declare, read
    here from the XML text itself."""
    declared_joints, declared_actuators = [], []
    for name in ("robot.xml", "pick_and_place.xml"):
        root = ET.parse(FOLDER / "assets" / "fetch" / name).getroot()
        declared_joints += [j.get("name") for j in root.iter("joint")]
        declared_actuators += [a.get("name") for a in root.iter("position")]
    task = load_task(FOLDER / "task.py")
    model = BoundTask.of(task).model
    assert sorted(model.joint(i).name for i in range(model.njnt)) == sorted(declared_joints)
    assert sorted(model.actuator(i).name for i in range(model.nu)) == sorted(declared_actuators)
    assert model.nmocap == 1 and model.neq == 1 and model.eq(0).name == ""  # the unnamed weld


def _suite_reset(model: mujoco.MjModel, values: dict[str, float]) -> tuple[np.ndarray, np.ndarray]:
    """fetch_env.py's `_env_setup` then `_reset_sim` and `_sample_goal`, written out literally:
    the initial state and the goal."""
    d = mujoco.MjData(model)
    for name, q in {"robot0:slide0": 0.405, "robot0:slide1": 0.48, "robot0:slide2": 0.0}.items():
        d.qpos[model.jnt_qposadr[model.joint(name).id]] = q
    adr = model.jnt_qposadr[model.joint("object0:joint").id]
    d.qpos[adr : adr + 7] = [1.25, 0.53, 0.4, 1.0, 0.0, 0.0, 0.0]
    for i in range(model.neq):  # reset_mocap_welds
        if model.eq_type[i] == mujoco.mjtEq.mjEQ_WELD:
            model.eq_data[i, :7] = [0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0]
    mujoco.mj_forward(model, d)
    grip = model.site("robot0:grip").id
    d.mocap_pos[0] = np.array([-0.498, 0.005, -0.431 + 0.2]) + d.site_xpos[grip]
    d.mocap_quat[0] = [1.0, 0.0, 1.0, 0.0]
    for _ in range(10):
        mujoco.mj_step(model, d, nstep=20)
    initial_gripper_xpos = d.site_xpos[grip].copy()
    height_offset = d.site_xpos[model.site("object0").id][2]
    goal = initial_gripper_xpos + [values["goal_dx"], values["goal_dy"], 0.0]
    goal[2] = height_offset + max(0.0, values["goal_lift"])
    qpos, qvel, time = d.qpos.copy(), d.qvel.copy(), d.time
    mujoco.mj_resetData(model, d)
    d.time, d.qpos[:], d.qvel[:] = time, qpos, qvel
    d.qpos[adr : adr + 2] = initial_gripper_xpos[:2] + [values["object_dx"], values["object_dy"]]
    mujoco.mj_forward(model, d)
    state = np.empty(mujoco.mj_stateSize(model, FULLPHYSICS))
    mujoco.mj_getState(model, d, state, FULLPHYSICS)
    return state, goal


def test_an_episode_starts_where_the_suites_reset_leaves_it():
    task = load_task(FOLDER / "task.py")
    bound = BoundTask.of(task)
    values = {
        "object_dx": 0.12,
        "object_dy": -0.05,
        "goal_dx": 0.1,
        "goal_dy": 0.0,
        "goal_lift": 0.2,
    }
    model, state = bound.episode(values, scratch=mujoco.MjData(bound.model))
    reference = load_model(task.model)
    suite_state, suite_goal = _suite_reset(reference, values)
    np.testing.assert_array_equal(state, suite_state)
    np.testing.assert_array_equal(model.eq_data, reference.eq_data)  # the welds reset
    data = mujoco.MjData(model)
    mujoco.mj_setState(model, data, state, FULLPHYSICS)
    mujoco.mj_forward(model, data)
    np.testing.assert_allclose(data.site("target0").xpos, suite_goal, rtol=0, atol=1e-12)


@pytest.fixture(scope="module")
def fetch_run(tmp_path_factory) -> Path:
    workdir = tmp_path_factory.mktemp("fetch")
    copy_workflow(workdir)
    config = yaml.safe_load((REPO_ROOT / "config" / "fetch_pick.yaml").read_text())
    config["experiment"] = "fetch_small"
    config["states"]["n"] = 12
    config["analysis"]["n_resamples"] = 200
    (workdir / CONFIG).write_text(yaml.safe_dump(config, sort_keys=False))
    run_snakemake(workdir, "--configfile", CONFIG)
    return workdir


def test_every_block_obeys_the_suites_redraw_rule_and_the_redraws_are_counted(fetch_run):
    """The states are the first n rows, in draw order, of rounds of the plain uniform draw that
    keep the block 10 cm from the gripper; the rejected rows before the n-th are counted, in
    the manifest and the report. Recomputed here row by row."""
    states = pq.read_table(fetch_run / RESULTS / "states.parquet").to_pydict()
    ranges = yaml.safe_load((REPO_ROOT / "config" / "fetch_pick.yaml").read_text())["states"][
        "ranges"
    ]
    n, rng, kept, rejected = 12, np.random.default_rng(2026), [], 0
    while len(kept) < n:
        rows = np.column_stack([rng.uniform(lo, hi, n) for lo, hi in ranges.values()])
        for row in rows:
            if len(kept) == n:
                break
            if np.hypot(row[0], row[1]) >= 0.1:
                kept.append(row)
            else:
                rejected += 1
    drawn = np.column_stack([states[p] for p in ranges])
    np.testing.assert_array_equal(drawn, np.array(kept))
    manifest = yaml.safe_load((fetch_run / RESULTS / "manifest.json").read_text())
    assert manifest["states_redrawn"]["evaluation"] == rejected > 0
    report = (fetch_run / RESULTS / "report.md").read_text()
    assert f"draws rejected and redrawn: {rejected} for the evaluation states" in report


def test_the_report_says_what_drives_the_arm(fetch_run):
    report = (fetch_run / RESULTS / "report.md").read_text()
    assert "weld 0 (robot0:mocap to robot0:gripper_link): active" in report
    assert (
        "columns 0-2: the target position of mocap body `robot0:mocap` = the pose of "
        "`robot0:gripper_link` as the last physics step left it + 0.05 × the values, each axis "
        "clipped to ±0.05 m per control step" in report
    )
    assert "unbounded" not in report.split("## Metric")[0].replace("force unbounded", "")


def test_it_verifies_and_a_failure_replays_as_recorded(fetch_run, monkeypatch, capsys):
    monkeypatch.chdir(fetch_run)
    assert main(["verify", RESULTS, "--config", CONFIG, "--resimulate", "4"]) == 0
    rows = pq.read_table(fetch_run / RESULTS / "rollouts" / "noise_40mm.parquet").to_pylist()
    failed = next((r for r in rows if not r["success"]), rows[0])
    out = fetch_run / "replayed.rrd"
    code = main(
        [
            "replay",
            RESULTS,
            "--config",
            CONFIG,
            "--condition",
            "noise_40mm",
            "--state",
            str(failed["state_id"]),
            "--output",
            str(out),
            "--no-viewer",
        ]
    )
    assert code == 0, capsys.readouterr().out
    assert "as recorded" in capsys.readouterr().out
