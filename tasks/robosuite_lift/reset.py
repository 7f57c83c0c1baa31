"""robosuite 1.5.2's Lift reset, in numpy and MuJoCo alone: the initial qpos of an episode.

robosuite's reset (`Robot.reset`, `Lift._reset_internal`, `UniformRandomSampler`) puts the
arm at Panda's `init_qpos` plus a normal draw (standard deviation 0.02 rad per joint), the
fingers at (0.020833, -0.020833), and the cube on the table: its centre at (x, y) uniform in
[-0.03, 0.03] m from the table's centre, at z = 0.8 (the table's top) + 0.01 (the sampler's
z_offset) + the cube's half height, yawed about z by an angle uniform in [0, 2 pi). Velocities
are zero. The model is built once per hard reset with a new cube size (each half-extent uniform
in [0.020, 0.022] m); `lift.xml` holds the one drawn with seed 0.
"""

from __future__ import annotations

import mujoco
import numpy as np

from robosuite_lift.osc_reference import ARM_JOINTS, GRIPPER_INIT_QPOS, GRIPPER_JOINTS, INIT_QPOS

CUBE_JOINT, CUBE_GEOM = "cube_joint0", "cube_g0"
TABLE_OFFSET = np.array((0, 0, 0.8))  # the table's top centre (Lift's table_offset)
Z_OFFSET = 0.01  # the placement sampler's z_offset
CUBE_XY_RANGE = (-0.03, 0.03)  # m, each of x and y, from the table's centre
CUBE_YAW_RANGE = (0.0, 2 * np.pi)  # rad, about z
SUCCESS_HEIGHT = TABLE_OFFSET[2] + 0.04  # Lift._check_success: the cube's centre z above this


def initial_qpos(model: mujoco.MjModel, cube_x, cube_y, cube_yaw, noise) -> np.ndarray:
    """The qpos robosuite's reset leaves for these draws (`noise`: 7 radians added to
    init_qpos), in robosuite's arithmetic."""
    qpos = model.qpos0.copy()

    def adr(name: str) -> int:
        return model.jnt_qposadr[model.joint(name).id]

    qpos[[adr(j) for j in ARM_JOINTS]] = INIT_QPOS + np.asarray(noise, dtype=np.float64)
    qpos[[adr(j) for j in GRIPPER_JOINTS]] = GRIPPER_INIT_QPOS
    half_height = model.geom_size[model.geom(CUBE_GEOM).id][2]
    z = Z_OFFSET + TABLE_OFFSET[2] - (-1 * half_height)
    pos = [cube_x + TABLE_OFFSET[0], cube_y + TABLE_OFFSET[1], z]
    quat = [np.cos(cube_yaw / 2), 0, 0, np.sin(cube_yaw / 2)]
    cube = adr(CUBE_JOINT)
    qpos[cube : cube + 7] = np.concatenate([np.array(pos), np.array(quat)])
    return qpos
