"""Calibration of the gantry gripper on DEVELOPMENT states only (never the evaluation seed).

Prints success per mass band for the fast and slow lifts, for the model as it is and for
variants of its physical parameters, so the README's calibration table can be reproduced:

    python models/gantry_gripper/calibrate.py                  # the model as it is
    python models/gantry_gripper/calibrate.py --grip 14 18 22  # vary the grip-force limit
    python models/gantry_gripper/calibrate.py --timestep 0.004  # convergence check
"""

from __future__ import annotations

import argparse
import sys

import mujoco
import numpy as np
import yaml

from mjtrial import REPO_ROOT, model_path
from mjtrial.design.states import generate_initial_states
from mjtrial.sim.physics import load_model

# The gantry's own modules live in its task package, tasks/gantry_lift.
sys.path.insert(0, str(REPO_ROOT / "tasks"))
from gantry_lift.model_spec import ModelSpec  # noqa: E402
from gantry_lift.protocol import PROTOCOL  # noqa: E402
from gantry_lift.simulate import iter_episode_batches  # noqa: E402
from gantry_lift.states import STATE_PARAMETERS, states_from_table  # noqa: E402

BANDS = (0.05, 0.23, 0.42, 0.6)


def variant(*, grip=None, friction=None, torsion=None, z_kp=None, timestep=None) -> mujoco.MjModel:
    """The model with some physical parameters replaced (through MjSpec, not text edits)."""
    spec = mujoco.MjSpec.from_file(str(model_path("gantry_gripper")))
    if timestep is not None:
        spec.option.timestep = timestep
    for geom in spec.geoms:
        if geom.name in ("left_pad", "right_pad", "cube"):
            if friction is not None:
                geom.friction[0] = friction
            if torsion is not None:
                geom.friction[1] = torsion
    for act in spec.actuators:
        if act.name == "gripper" and grip is not None:
            act.forcerange = [-grip, grip]
        if act.name == "z" and z_kp is not None:
            act.gainprm[0] = z_kp
            act.biasprm[1] = -z_kp
    return spec.compile()


def band_rates(model, states, lift_time: float) -> tuple[float, list[float]]:
    success = np.concatenate(
        [
            b.physics[:, -1, ModelSpec.of(model).state_cube_z] > PROTOCOL.success_height
            for b in iter_episode_batches(model, states, lift_time=lift_time, nthread=2)
        ]
    )
    mass = np.array([s.mass for s in states])
    band = np.clip(np.searchsorted(BANDS, mass, side="right") - 1, 0, 2)
    return float(success.mean()), [float(success[band == k].mean()) for k in range(3)]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--n", type=int, default=400, help="development states")
    for name in ("grip", "friction", "torsion", "z_kp", "timestep"):
        parser.add_argument(f"--{name.replace('_', '-')}", type=float, nargs="+", default=[None])
    args = parser.parse_args()
    config = yaml.safe_load((REPO_ROOT / "config" / "config.yaml").read_text())
    s = config["states"]
    states = states_from_table(
        generate_initial_states(
            seed=s["development_seed"], n=args.n, ranges=s["ranges"], parameters=STATE_PARAMETERS
        )
    )
    load_model(model_path("gantry_gripper"))  # the checks the pipeline applies
    print(f"development seed {s['development_seed']}, n = {args.n}; bands {BANDS} kg")
    for grip in args.grip:
        for friction in args.friction:
            for torsion in args.torsion:
                for z_kp in args.z_kp:
                    for timestep in args.timestep:
                        kw = dict(
                            grip=grip,
                            friction=friction,
                            torsion=torsion,
                            z_kp=z_kp,
                            timestep=timestep,
                        )
                        model = variant(**kw)
                        label = ", ".join(f"{k}={v:g}" for k, v in kw.items() if v is not None)
                        row = [label or "as built"]
                        for lift_time in (0.15, 1.5):
                            pooled, bands = band_rates(model, states, lift_time)
                            row.append(
                                f"{lift_time:g} s: {pooled:.2f} "
                                + " ".join(f"{b:.2f}" for b in bands)
                            )
                        print(" | ".join(row), flush=True)


if __name__ == "__main__":
    main()
