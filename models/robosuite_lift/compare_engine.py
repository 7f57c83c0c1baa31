"""mjtrial's engine against robosuite's own env, on the reference episodes.

Runs `tasks/robosuite_lift/` through `mjtrial.sim.engine.iter_batches` (the policy at 20 Hz,
`OperationalSpace` at every physics step, as a rollout job runs it) from the initial states of
`tests/data/robosuite_lift_reference.json` (robosuite 1.5.2's env, written by
`reference_runs.py`), under each of its conditions, and prints how the outcomes and the grip
site's positions at each action compare. Runs in mjtrial's own environment (MuJoCo 3.14.0):

    python models/robosuite_lift/compare_engine.py [REFERENCE.json]
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import mujoco
import numpy as np

from mjtrial import REPO_ROOT
from mjtrial.sim.engine import iter_batches
from mjtrial.sim.physics import FULLPHYSICS, load_model
from mjtrial.task import BoundTask, load_task

sys.path.insert(0, str(REPO_ROOT / "tasks"))
from robosuite_lift.osc_reference import GRIP_SITE  # noqa: E402
from robosuite_lift.task import N_SUBSTEPS  # noqa: E402

REFERENCE = REPO_ROOT / "tests" / "data" / "robosuite_lift_reference.json"


def values_of(states) -> dict[str, np.ndarray]:
    """The task's state parameters from the reference's states (robosuite's draws)."""
    out = {
        "cube_dx": np.array([s["cube_x"] for s in states]),
        "cube_dy": np.array([s["cube_y"] for s in states]),
        "cube_yaw": np.array([s["cube_yaw"] for s in states]),
    }
    for k in range(7):
        out[f"joint{k + 1}_noise"] = np.array([s["noise"][k] for s in states])
    return out


def grip_positions(model: mujoco.MjModel, initial: np.ndarray, physics: np.ndarray) -> np.ndarray:
    """(n_actions + 1, 3) the grip site where robosuite's `robot0_eef_pos` reads it: at the
    reset, then after each action as the action's last `mj_step1` computed it (the state one
    physics step before the action's end)."""
    data = mujoco.MjData(model)
    site = model.site(GRIP_SITE).id
    rows = [initial] + [
        physics[k * N_SUBSTEPS - 2] for k in range(1, len(physics) // N_SUBSTEPS + 1)
    ]
    out = []
    for row in rows:
        mujoco.mj_setState(model, data, row, FULLPHYSICS)
        mujoco.mj_kinematics(model, data)
        out.append(data.site_xpos[site].copy())
    return np.array(out)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("reference", nargs="?", type=Path, default=REFERENCE)
    reference = json.loads(parser.parse_args().reference.read_text())
    task = load_task(REPO_ROOT / "tasks" / "robosuite_lift" / "task.py")
    bound = BoundTask.of(task, load_model(task.model))
    values = values_of(reference["states"])
    print(
        f"robosuite {reference['robosuite']} on MuJoCo {reference['mujoco']} against mjtrial's "
        f"engine on MuJoCo {mujoco.__version__}, {len(reference['states'])} states:"
    )
    for condition, summary in reference["summary"].items():
        episodes = {e["state_id"]: e for e in reference["episodes"] if e["condition"] == condition}
        success, diffs = [], []
        for batch in iter_batches(
            bound, values, {"close_steps": summary["close_steps"]}, thresholds={}
        ):
            for i in range(len(batch.episodes.physics)):
                sid = len(success)
                m, start = bound.episode(
                    {k: float(v[sid]) for k, v in values.items()},
                    scratch=mujoco.MjData(bound.model),
                )
                ours = grip_positions(m, start, batch.episodes.physics[i])
                theirs = np.array(episodes[sid]["eef_pos"])
                diffs.append(float(np.abs(ours - theirs).max()))
                success.append(bool(batch.outcome["success"][i]))
        theirs_success = [episodes[i]["success"] for i in range(len(success))]
        agree = sum(a == b for a, b in zip(success, theirs_success, strict=True))
        print(
            f"  {condition}: robosuite {sum(theirs_success)}/{len(success)} lifted, the engine "
            f"{sum(success)}/{len(success)}; outcomes agree on {agree}/{len(success)}; the grip "
            f"site's largest difference per episode: median {np.median(diffs) * 1e3:.2g} mm, "
            f"max {max(diffs) * 1e3:.2g} mm"
        )


if __name__ == "__main__":
    main()
