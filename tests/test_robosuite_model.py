"""robosuite's Lift as exported (`models/robosuite_lift/`) and the re-implementation of its
controllers (`tasks/robosuite_lift/osc_reference.py`), in this environment's MuJoCo.

The controls expected here are robosuite's own: `tests/data/robosuite_lift_controls.npz` holds
ten actions of an episode run in robosuite 1.5.2's env (MuJoCo 3.9.0, numpy 1.26, robosuite's
numba functions), with the state each physics step started from and the controls robosuite
wrote (`models/robosuite_lift/check_reference.py --fixture`)."""

from __future__ import annotations

import hashlib
import json
import re

import mujoco
import numpy as np
import pytest
from conftest import REPO_ROOT
from robosuite_lift import osc_reference

FOLDER = REPO_ROOT / "models" / "robosuite_lift"
XML = FOLDER / "lift.xml"
CONTROLS = REPO_ROOT / "tests" / "data" / "robosuite_lift_controls.npz"
ROW = re.compile(r"^\| `([^`]+)` \| (\d+) \| `([0-9a-f]{64})` \|$")


def readme_hashes() -> dict[str, tuple[int, str]]:
    text = (FOLDER / "README.md").read_text(encoding="utf-8")
    rows = [ROW.match(line) for line in text.splitlines()]
    return {m[1]: (int(m[2]), m[3]) for m in rows if m}


def test_readme_lists_every_file_the_model_names_with_its_sha256():
    table = readme_hashes()
    named = set(re.findall(r'<mesh\b[^>]*?\bfile="([^"]+)"', XML.read_text()))
    textures = set(re.findall(r'<texture\b[^>]*?\bfile="([^"]+)"', XML.read_text()))
    expected = {"lift.xml"} | {f"meshes/{p}" for p in named} | textures
    assert set(table) == expected
    for path, (size, sha256) in table.items():
        data = (FOLDER / path).read_bytes()
        assert (len(data), hashlib.sha256(data).hexdigest()) == (size, sha256), path


@pytest.fixture(scope="module")
def model():
    return mujoco.MjModel.from_xml_path(str(XML))


def test_model_compiles_and_steps_without_warnings(model):
    assert (model.opt.timestep, model.opt.density, model.opt.viscosity) == (0.002, 1.2, 2e-5)
    data = mujoco.MjData(model)
    data.qpos[osc_reference.Ids.of(model).arm_qpos] = osc_reference.INIT_QPOS
    mujoco.mj_forward(model, data)
    for _ in range(1000):
        mujoco.mj_step(model, data)
    assert [w.number for w in data.warning] == [0] * mujoco.mjtWarning.mjNWARNING.value
    assert np.isfinite(data.qpos).all()


def test_controls_equal_robosuites_at_every_physics_step(model):
    """Each physics step starts from robosuite's recorded state; the reference's controls
    must equal robosuite's to rounding (robosuite's numba LAPACK calls are not numpy's)."""
    run = np.load(CONTROLS)
    data = mujoco.MjData(model)
    ids = osc_reference.Ids.of(model)
    data.qpos[:], data.qvel[:] = run["qpos"][0], run["qvel"][0]
    mujoco.mj_forward(model, data)
    state = osc_reference.start(model, data, ids)
    ctrls = []
    for k in range(len(run["ctrl"])):
        data.qpos[:], data.qvel[:] = run["qpos"][k], run["qvel"][k]
        mujoco.mj_step1(model, data)
        action = run["actions"][k // 25]
        ctrls.append(osc_reference.ctrl(model, data, ids, state, action, new_action=k % 25 == 0))
    ctrls = np.array(ctrls)
    assert len(ctrls) == 250
    assert np.abs(ctrls - run["ctrl"]).max() < 1e-9
    # the fixture exercises what it should: torques clipped and not, the gripper both ways
    arm = ids.arm_actuators
    assert (np.abs(run["ctrl"][:, arm]) == model.actuator_ctrlrange[arm, 1]).any()
    assert len(np.unique(run["ctrl"][:, ids.gripper_actuators[0]])) > 2



REFERENCE = REPO_ROOT / "tests" / "data" / "robosuite_lift_reference_mujoco3.14.json"


def test_plain_loop_replays_robosuites_episodes():
    """The reset, the controllers and the scripted policy in a plain MuJoCo loop reproduce
    robosuite's own episodes (`reference_runs.py` on MuJoCo 3.14.0, robosuite's env with the
    shims of `mujoco_compat.py`): a lifted one and a dropped one, from their initial states.
    Within 1e-6 m, not bit for bit: the controls differ from robosuite's in the last bits
    (numba's LAPACK), which a contact solve can carry up to about 1e-7 m over an episode."""
    from robosuite_lift import plain_loop

    ref = json.loads(REFERENCE.read_text(encoding="utf-8"))
    assert ref["mujoco"] == mujoco.__version__
    model = mujoco.MjModel.from_xml_path(str(XML))
    states = {s["state_id"]: s for s in ref["states"]}
    close_2 = [e for e in ref["episodes"] if e["condition"] == "close_2"]
    lifted = next(e for e in close_2 if e["success"])
    dropped = next(e for e in close_2 if not e["success"])
    for e in (lifted, dropped):
        mine = plain_loop.from_state(model, states[e["state_id"]], 2)
        assert mine["success"] == e["success"]
        np.testing.assert_allclose(mine["eef_pos"], e["eef_pos"], rtol=0, atol=1e-6)
        np.testing.assert_allclose(mine["final_cube_qpos"], e["final_cube_qpos"], rtol=0, atol=1e-6)
