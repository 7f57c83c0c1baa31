"""Check `tasks/robosuite_lift/osc_reference.py` against robosuite's own env.

Run from the repository's root: `python models/robosuite_lift/check_reference.py` (it builds
and uses robosuite's environment, `rsenv.py`). For each of a few initial states (the cube's
place and yaw, the arm's initial joint noise) and a sequence of random actions (the arm's six
numbers uniform in [-1, 1], the gripper's sign random), it runs robosuite's `env.step` and, on
the same initial state (`mj_getState`/`mj_setState` of robosuite's data after its reset), the
plain loop `mj_step1`, `osc_reference.ctrl`, `mj_step2` on `lift.xml`, both in this MuJoCo.
It prints the largest difference of the controls at any physics step, and of the grip site's
position (as each `mj_step1` computes it) and of the final state.

`--fixture FILE` also writes the first episode's first `--fixture-actions` actions as robosuite
ran them (`numpy.savez_compressed`): `actions`, and at every physics step the `qpos` and `qvel`
that `mj_step1` started from and the `ctrl` robosuite's controllers wrote. With it,
`tests/test_robosuite_model.py` checks `osc_reference` in another MuJoCo and numpy.
"""

from __future__ import annotations

import argparse
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
from robosuite_lift import osc_reference  # noqa: E402

STATE = mujoco.mjtState.mjSTATE_INTEGRATION


def robosuite_episode(env, actions) -> tuple[np.ndarray, np.ndarray, np.ndarray, dict]:
    """robosuite's env stepped through `actions`: the controls and the grip site's position
    at every physics step, the final state, and the qpos, qvel and ctrl of every step."""
    sim = env.sim
    site = sim.model.site_name2id(osc_reference.GRIP_SITE)
    ctrls, sites, qpos, qvel = [], [], [], []
    step1, step2 = sim.step1, sim.step2

    def recording_step1():
        qpos.append(np.array(sim.data.qpos))
        qvel.append(np.array(sim.data.qvel))
        step1()
        sites.append(np.array(sim.data.site_xpos[site]))

    def recording_step2():
        ctrls.append(np.array(sim.data.ctrl))
        step2()

    sim.step1, sim.step2 = recording_step1, recording_step2
    try:
        for action in actions:
            env.step(action)
    finally:
        sim.step1, sim.step2 = step1, step2
    recorded = {"qpos": np.array(qpos), "qvel": np.array(qvel), "ctrl": np.array(ctrls)}
    final = full_state(sim.model._model, sim.data._data)
    return np.array(ctrls), np.array(sites), final, recorded


def full_state(model, data) -> np.ndarray:
    out = np.empty(mujoco.mj_stateSize(model, STATE))
    mujoco.mj_getState(model, data, out, STATE)
    return out


def plain_episode(model, initial, actions) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    data = mujoco.MjData(model)
    mujoco.mj_setState(model, data, initial, STATE)
    mujoco.mj_forward(model, data)
    site = osc_reference.Ids.of(model).grip_site
    ctrls, sites = [], []

    def record(d):
        ctrls.append(np.array(d.ctrl))
        sites.append(np.array(d.site_xpos[site]))

    osc_reference.episode(model, data, actions, on_step=record)
    return np.array(ctrls), np.array(sites), full_state(model, data)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--episodes", type=int, default=5)
    parser.add_argument("--seconds", type=float, default=1.0)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--json", type=Path, help="also write the figures here")
    parser.add_argument("--fixture", type=Path, help="write robosuite's first episode here")
    parser.add_argument("--fixture-actions", type=int, default=10)
    args = parser.parse_args()
    env = make_env(hard_reset=False)
    model = mujoco.MjModel.from_xml_path(str(HERE / "lift.xml"))
    same_model(env.sim.model._model, model)
    rng = np.random.default_rng(args.seed)
    n_actions = round(args.seconds * env.control_freq)
    rows = []
    for episode in range(args.episodes):
        x, y = rng.uniform(-0.03, 0.03, 2)
        yaw = rng.uniform(0, 2 * np.pi)
        noise = rng.standard_normal(7) * osc_reference.INIT_NOISE_STD
        actions = np.concatenate(
            [rng.uniform(-1, 1, (n_actions, 6)), rng.choice([-1.0, 1.0], (n_actions, 1))], axis=1
        )
        reset_to(env, x, y, yaw, noise)
        initial = full_state(env.sim.model._model, env.sim.data._data)
        rs_ctrl, rs_site, rs_final, recorded = robosuite_episode(env, actions)
        ref_ctrl, ref_site, ref_final = plain_episode(model, initial, actions)
        arm = osc_reference.Ids.of(model).arm_actuators
        rows.append(
            {
                "episode": episode,
                "physics_steps": len(rs_ctrl),
                "max_torque_diff_Nm": float(np.abs(rs_ctrl[:, arm] - ref_ctrl[:, arm]).max()),
                "max_ctrl_diff": float(np.abs(rs_ctrl - ref_ctrl).max()),
                "max_site_diff_mm": float(np.linalg.norm(rs_site - ref_site, axis=1).max() * 1e3),
                "final_state_max_diff": float(np.abs(rs_final - ref_final).max()),
                "bit_identical": bool(
                    np.array_equal(rs_ctrl, ref_ctrl) and np.array_equal(rs_final, ref_final)
                ),
            }
        )
        print(json.dumps(rows[-1]))
        if args.fixture and episode == 0:
            n = args.fixture_actions * 25
            np.savez_compressed(
                args.fixture,
                actions=actions[: args.fixture_actions],
                **{k: v[:n] for k, v in recorded.items()},
            )
    worst = {k: max(r[k] for r in rows) for k in rows[0] if k.startswith("max") or "final" in k}
    print(f"robosuite {rsenv.ROBOSUITE}, MuJoCo {mujoco.__version__}, numpy {np.__version__}: "
          f"{len(rows)} episodes of {args.seconds} s; worst: {json.dumps(worst)}")  # fmt: skip
    if args.json:
        args.json.write_text(json.dumps({"episodes": rows, "worst": worst}, indent=1) + "\n")


if __name__ == "__main__":
    main()
