"""Reference data from robosuite's own env: the scripted policy on given initial states.

Run from the repository's root (it builds and uses robosuite's environment, `rsenv.py`):

    python models/robosuite_lift/reference_runs.py --make-states 40 --seed 2026 \\
        --out tests/data/robosuite_lift_reference.json

or `--states FILE` for states of your own: a JSON list of objects with `state_id`, `cube_x`,
`cube_y` (m, from the table's centre), `cube_yaw` (rad) and `noise` (7 radians added to the
arm's init_qpos). `--make-states N` draws them as robosuite's reset does (x, y uniform in
[-0.03, 0.03], yaw uniform in [0, 2 pi), noise normal with standard deviation 0.02).

For each condition of `scripted.CONDITIONS` and each state it sets robosuite's env to that state
after its reset (`lift_env.reset_to`), runs `tasks/robosuite_lift/scripted.py` on robosuite's
observations and records the outcome (`env._check_success()` after the last action), the grip
site's observed position at every policy step (`robot0_eef_pos`, as the policy saw it) and the
cube's final pose (its joint's qpos: position, quaternion w x y z). Alongside, the same episode
as a plain loop of `mj_step1`, `osc_reference.ctrl`, `mj_step2` on `lift.xml` in the same
MuJoCo, whose outcome and grip-site trajectory are compared with robosuite's.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import sys
from pathlib import Path

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))
sys.path.insert(0, str(HERE.parent.parent / "tasks"))
import rsenv  # noqa: E402

rsenv.ensure()

import mujoco  # noqa: E402
import numpy as np  # noqa: E402
from lift_env import make_env, reset_to, same_model  # noqa: E402
from robosuite_lift import osc_reference, scripted  # noqa: E402

STATE = mujoco.mjtState.mjSTATE_INTEGRATION
KEYS = ("state_id", "cube_x", "cube_y", "cube_yaw", "noise")
CUBE_BODY, CUBE_JOINT = "cube_main", "cube_joint0"
TABLE_TOP_Z = 0.8  # the table's top (Lift's table_offset z); success: cube centre above + 0.04
SUCCESS_MARGIN = 0.04


def make_states(n: int, seed: int) -> list[dict]:
    rng = np.random.default_rng(seed)
    return [
        {
            "state_id": i,
            "cube_x": float(rng.uniform(-0.03, 0.03)),
            "cube_y": float(rng.uniform(-0.03, 0.03)),
            "cube_yaw": float(rng.uniform(0, 2 * np.pi)),
            "noise": [float(v) for v in rng.standard_normal(7) * osc_reference.INIT_NOISE_STD],
        }
        for i in range(n)
    ]


def load_states(path: Path) -> list[dict]:
    states = json.loads(path.read_text(encoding="utf-8"))
    if not isinstance(states, list):
        raise SystemExit(f"{path}: expected a JSON list of states")
    for i, s in enumerate(states):
        missing = [k for k in KEYS if k not in s]
        if missing:
            raise SystemExit(f"{path}: state {i} lacks {', '.join(missing)}")
        if len(s["noise"]) != 7:
            raise SystemExit(f"{path}: state {i}'s noise has {len(s['noise'])} numbers, not 7")
    return states


def robosuite_episode(env, state: dict, close_steps: int) -> dict:
    obs = reset_to(env, state["cube_x"], state["cube_y"], state["cube_yaw"], state["noise"])
    model, data = env.sim.model._model, env.sim.data._data
    initial = np.empty(mujoco.mj_stateSize(model, STATE))
    mujoco.mj_getState(model, data, initial, STATE)
    eef = [obs["robot0_eef_pos"]]
    site = env.sim.model.site_name2id(osc_reference.GRIP_SITE)
    for step in range(scripted.episode_steps(close_steps)):
        act = scripted.action(step, obs["robot0_eef_pos"], obs["cube_pos"], close_steps)
        obs, *_ = env.step(act)
        eef.append(obs["robot0_eef_pos"])
        if not np.array_equal(obs["robot0_eef_pos"], env.sim.data.site_xpos[site]):
            raise SystemExit(f"step {step}: robosuite's observation is not MuJoCo's data after "
                             "the action's last physics step")  # fmt: skip
    cube = env.sim.model.joint_name2id(CUBE_JOINT)
    adr = env.sim.model.jnt_qposadr[cube]
    return {
        "success": bool(env._check_success()),
        "eef_pos": np.array(eef),
        "final_cube_qpos": np.array(env.sim.data.qpos[adr : adr + 7]),
        "initial": initial,
    }


def plain_episode(model: mujoco.MjModel, initial: np.ndarray, close_steps: int) -> dict:
    """The same episode as a plain loop, the policy reading MuJoCo's data after each action's
    last `mj_step2` (the grip site's `site_xpos`, the cube's `xpos`: what robosuite observes)."""
    data = mujoco.MjData(model)
    mujoco.mj_setState(model, data, initial, STATE)
    mujoco.mj_forward(model, data)
    ids = osc_reference.Ids.of(model)
    cube = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_BODY, CUBE_BODY)
    state = osc_reference.start(model, data, ids)
    eef = [np.array(data.site_xpos[ids.grip_site])]
    for step in range(scripted.episode_steps(close_steps)):
        act = scripted.action(step, data.site_xpos[ids.grip_site], data.xpos[cube], close_steps)
        for i in range(25):
            mujoco.mj_step1(model, data)
            data.ctrl[:] = osc_reference.ctrl(model, data, ids, state, act, new_action=(i == 0))
            mujoco.mj_step2(model, data)
        eef.append(np.array(data.site_xpos[ids.grip_site]))
    return {
        "success": bool(data.xpos[cube][2] > TABLE_TOP_Z + SUCCESS_MARGIN),
        "eef_pos": np.array(eef),
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    source = parser.add_mutually_exclusive_group(required=True)
    source.add_argument("--states", type=Path, help="a JSON list of initial states")
    source.add_argument("--make-states", type=int, metavar="N", help="draw N states")
    parser.add_argument("--seed", type=int, default=2026, help="with --make-states")
    parser.add_argument("--out", type=Path, required=True, help="the JSON file to write")
    args = parser.parse_args()
    states = load_states(args.states) if args.states else make_states(args.make_states, args.seed)
    env = make_env(hard_reset=False)
    xml = HERE / "lift.xml"
    model = mujoco.MjModel.from_xml_path(str(xml))
    same_model(env.sim.model._model, model)
    episodes, summary = [], {}
    for condition, close_steps in scripted.CONDITIONS.items():
        agree, worst = 0, 0.0
        for s in states:
            rs = robosuite_episode(env, s, close_steps)
            plain = plain_episode(model, rs["initial"], close_steps)
            diff = float(np.linalg.norm(rs["eef_pos"] - plain["eef_pos"], axis=1).max())
            agree += rs["success"] == plain["success"]
            worst = max(worst, diff)
            episodes.append(
                {
                    "condition": condition,
                    "state_id": s["state_id"],
                    "success": rs["success"],
                    "final_cube_qpos": rs["final_cube_qpos"].tolist(),
                    "eef_pos": rs["eef_pos"].tolist(),
                    "plain_loop_success": plain["success"],
                    "plain_loop_max_eef_diff_m": diff,
                }
            )
        n = len(states)
        wins = sum(e["success"] for e in episodes if e["condition"] == condition)
        summary[condition] = {
            "close_steps": close_steps,
            "episodes": n,
            "successes": wins,
            "plain_loop_outcomes_agree": agree,
            "plain_loop_max_eef_diff_m": worst,
        }
        print(f"{condition}: {wins}/{n} lifted; the plain loop agrees on {agree}/{n}, "
              f"grip site within {worst * 1e3:.3g} mm", flush=True)  # fmt: skip
    out = {
        "robosuite": rsenv.ROBOSUITE,
        "mujoco": mujoco.__version__,
        "numpy": np.__version__,
        "model": "models/robosuite_lift/lift.xml",
        "model_sha256": hashlib.sha256(xml.read_bytes()).hexdigest(),
        "policy": "tasks/robosuite_lift/scripted.py",
        "policy_steps_per_second": 20,
        "physics_steps_per_policy_step": 25,
        "eef_pos": "robot0_eef_pos (grip site, world, m) at reset and after each policy step",
        "final_cube_qpos": "cube_joint0's qpos after the last step: x y z, quaternion w x y z",
        "success": "robosuite's Lift._check_success after the last step: cube_main's xpos z "
        "> 0.8 + 0.04 (xpos as the last mj_step1 computed it)",
        "states": states,
        "summary": summary,
        "episodes": episodes,
    }
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(out) + "\n", encoding="utf-8")
    print(f"wrote {args.out} ({args.out.stat().st_size} bytes)")


if __name__ == "__main__":
    main()
