"""CPU seconds robosuite's own env spends on each of the given Lift episodes (run by
`bench_low_level.py`; it runs in robosuite 1.5.2's environment, `models/robosuite_lift/rsenv.py`).

Each episode: the env reset to the state (not timed), then the scripted policy's actions
stepped through `env.step` (timed: the process's CPU time), as `bench_low_level.py`'s plain loop
and engine step them. Reads a JSON list of states from the file given, prints a JSON list of
seconds, one per episode.

    python benchmarks/robosuite_env_time.py STATES.json CLOSE_STEPS
"""

from __future__ import annotations

import json
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path[:0] = [str(ROOT / "models" / "robosuite_lift"), str(ROOT / "tasks")]

import rsenv  # noqa: E402

rsenv.ensure()

import numpy as np  # noqa: E402
from lift_env import make_env, reset_to  # noqa: E402
from robosuite_lift import scripted  # noqa: E402


def main() -> None:
    states = json.loads(Path(sys.argv[1]).read_text())
    close_steps = int(sys.argv[2])
    env = make_env(hard_reset=False)
    seconds = []
    for s in states:
        obs = reset_to(env, s["cube_dx"], s["cube_dy"], s["cube_yaw"], np.array(s["noise"]))
        start = time.process_time()
        for step in range(scripted.episode_steps(close_steps)):
            action = scripted.action(step, obs["robot0_eef_pos"], obs["cube_pos"], close_steps)
            obs, *_ = env.step(action)
        seconds.append(time.process_time() - start)
    print(json.dumps(seconds))


if __name__ == "__main__":
    main()
