"""The scripted policy on robosuite's Lift as a plain MuJoCo loop, one episode at a time.

Each policy step: the policy reads MuJoCo's data as the last `mj_step2` left it (the grip
site's `site_xpos` and the cube's `xpos`, as `mj_step1` computed them: what robosuite's
observations hold), then 25 physics steps of `mj_step1`, `osc_reference.ctrl`, `mj_step2`.

Run as a script (`python tasks/robosuite_lift/plain_loop.py
tests/data/robosuite_lift_reference.json`), it replays robosuite's reference episodes in this
environment's MuJoCo, from the initial states their file lists, and prints how the outcomes
and grip-site trajectories compare.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import mujoco
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # tasks/, for a script
from robosuite_lift import osc_reference, reset, scripted  # noqa: E402

PHYSICS_STEPS = 25  # per policy step: 20 Hz actions, 2 ms physics
CUBE_BODY = "cube_main"


def episode(model: mujoco.MjModel, data: mujoco.MjData, close_steps: int) -> dict:
    """Run the scripted episode from the state in `data` (after `mj_forward`): its outcome,
    the grip site's observed position at reset and after each policy step, the cube's final
    qpos."""
    ids = osc_reference.Ids.of(model)
    cube = model.body(CUBE_BODY).id
    state = osc_reference.start(model, data, ids)
    eef = [np.array(data.site_xpos[ids.grip_site])]
    for step in range(scripted.episode_steps(close_steps)):
        act = scripted.action(step, data.site_xpos[ids.grip_site], data.xpos[cube], close_steps)
        for i in range(PHYSICS_STEPS):
            mujoco.mj_step1(model, data)
            data.ctrl[:] = osc_reference.ctrl(model, data, ids, state, act, new_action=(i == 0))
            mujoco.mj_step2(model, data)
        eef.append(np.array(data.site_xpos[ids.grip_site]))
    joint = model.jnt_qposadr[model.body_jntadr[cube]]
    return {
        "success": bool(data.xpos[cube][2] > reset.SUCCESS_HEIGHT),
        "eef_pos": np.array(eef),
        "final_cube_qpos": np.array(data.qpos[joint : joint + 7]),
    }


def from_state(model: mujoco.MjModel, state: dict, close_steps: int) -> dict:
    """The episode from one of `reference_runs.py`'s initial states, reset as robosuite does."""
    data = mujoco.MjData(model)
    data.qpos[:] = reset.initial_qpos(
        model, state["cube_x"], state["cube_y"], state["cube_yaw"], state["noise"]
    )
    mujoco.mj_forward(model, data)
    return episode(model, data, close_steps)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("reference", type=Path, help="reference_runs.py's output")
    parser.add_argument("--model", type=Path, default=Path("models/robosuite_lift/lift.xml"))
    args = parser.parse_args()
    ref = json.loads(args.reference.read_text(encoding="utf-8"))
    model = mujoco.MjModel.from_xml_path(str(args.model))
    states = {s["state_id"]: s for s in ref["states"]}
    rows = {}
    start = time.process_time()
    for e in ref["episodes"]:
        close_steps = ref["summary"][e["condition"]]["close_steps"]
        mine = from_state(model, states[e["state_id"]], close_steps)
        diff = np.linalg.norm(mine["eef_pos"] - np.array(e["eef_pos"]), axis=1).max()
        row = rows.setdefault(e["condition"], {"n": 0, "ref": 0, "plain": 0, "agree": 0, "d": []})
        row["n"] += 1
        row["ref"] += e["success"]
        row["plain"] += mine["success"]
        row["agree"] += mine["success"] == e["success"]
        row["d"].append(diff)
    cpu = (time.process_time() - start) / len(ref["episodes"])
    here = f"MuJoCo {mujoco.__version__}, numpy {np.__version__}"
    there = f"robosuite {ref['robosuite']} on MuJoCo {ref['mujoco']}"
    print(f"{here} against {there}; {cpu:.2f} s of CPU per episode")
    for c, r in rows.items():
        d = np.array(r["d"]) * 1e3
        print(f"{c}: robosuite {r['ref']}/{r['n']}, plain loop {r['plain']}/{r['n']}, "
              f"outcomes agree {r['agree']}/{r['n']}; grip site max difference: median "
              f"{np.median(d):.3g} mm, largest {d.max():.3g} mm")  # fmt: skip


if __name__ == "__main__":
    main()
