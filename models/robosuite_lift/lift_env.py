"""robosuite's Lift for the scripts beside this file: the env as exported, and a reset to a
given state. Import after `rsenv.ensure()` (it imports robosuite)."""

from __future__ import annotations

import numpy as np
import robosuite

SEED = 0  # the env's seed: it draws the cube's size when the model is built


def make_env(hard_reset: bool = True):
    """Lift as `suite.make` builds it by default, renderers off (they add nothing to the
    model). With `hard_reset=False` a reset keeps the model built here (the exported one)
    instead of building another with a new cube size."""
    return robosuite.make(
        "Lift",
        robots="Panda",
        has_renderer=False,
        has_offscreen_renderer=False,
        use_camera_obs=False,
        seed=SEED,
        hard_reset=hard_reset,
    )


class _Draw:
    """Stands in for the env's generator in `Robot.reset`: its one normal draw is `noise`."""

    def __init__(self, noise):
        self.noise = np.asarray(noise, dtype=np.float64)

    def standard_normal(self, n):
        assert n == len(self.noise)
        return self.noise.copy()


def reset_to(env, cube_x: float, cube_y: float, cube_yaw: float, noise) -> dict:
    """Reset `env`, then put it in the given state the way robosuite's reset would have:
    the arm at init_qpos + `noise` (the draw that robosuite scales by 0.02; given here as the
    radians themselves), the controllers made anew there (their nullspace target is that
    pose), the fingers at their initial opening, the cube at (x, y) relative to the table's
    centre, yawed by `cube_yaw`, at the sampler's height. Returns the observation.

    The observables' sampling clocks are restarted as `env.reset` leaves them (one forced
    update): robosuite samples an observation when its clock passes 1/control_freq, so an
    extra forced update here would move every later sample one physics step earlier."""
    env.reset()
    robot = env.robots[0]
    magnitude = robot.initialization_noise["magnitude"]
    robot.initialization_noise["magnitude"] = 1.0
    try:
        robot.reset(deterministic=False, rng=_Draw(noise))
    finally:
        robot.initialization_noise["magnitude"] = magnitude
    sampler = env.placement_initializer
    z = sampler.z_offset + sampler.reference_pos[2] - env.cube.bottom_offset[-1]
    pos = np.array([cube_x + sampler.reference_pos[0], cube_y + sampler.reference_pos[1], z])
    quat = np.array([np.cos(cube_yaw / 2), 0, 0, np.sin(cube_yaw / 2)])
    env.sim.data.set_joint_qpos(env.cube.joints[0], np.concatenate([pos, quat]))
    env.sim.forward()
    for observable in env._observables.values():
        observable.reset()
    return env._get_observations(force_update=True)


def same_model(built, exported) -> None:
    """Raise unless every numeric array and option of the two MjModels is equal (the asset
    paths aside: the model keeps them, and they are what the export changes)."""
    for name in dir(built):
        value = getattr(built, name, None)
        if name.startswith("_") or callable(value) or "path" in name:
            continue
        if isinstance(value, np.ndarray) and not np.array_equal(
            value, getattr(exported, name), equal_nan=True
        ):
            raise SystemExit(f"lift.xml's {name} differs from robosuite's model")
    for group in ("opt", "vis", "stat"):
        a, b = getattr(built, group), getattr(exported, group)
        for name in dir(a):
            if not name.startswith("_") and not callable(getattr(a, name)):
                if not np.array_equal(np.asarray(getattr(a, name)), np.asarray(getattr(b, name))):
                    raise SystemExit(f"lift.xml's {group}.{name} differs from robosuite's model")
