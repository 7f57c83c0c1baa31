"""Three shims that let robosuite 1.5.2 run on MuJoCo 3.14.0, for a same-version comparison.

robosuite 1.5.2 stops on MuJoCo 3.14.0 at three places of its own Python, none of them in the
model: `MjModel.get_joint_qpos_addr` and `get_joint_qvel_addr` assert
`jnt_type in (mjJNT_HINGE, mjJNT_SLIDE)`, False for a hinge under 3.14's bindings; and
`Controller.update` calls `mj_fullM(model, dst, data.qM)`, where MuJoCo 3.10 made it
`mj_fullM(model, data, dst)` and 3.14's `MjData` has no `qM`. `apply()` replaces those three
methods with the same lookups and the same dense mass matrix through the new call; nothing of
robosuite's arithmetic changes. `rsenv.ensure()` applies them when `ROBOSUITE_MUJOCO=3.14.0`
selects that environment.
"""

from __future__ import annotations

import mujoco
import numpy as np
import robosuite.controllers.parts.controller as controller
import robosuite.utils.binding_utils as binding_utils

WIDTH = {mujoco.mjtJoint.mjJNT_FREE: (7, 6), mujoco.mjtJoint.mjJNT_BALL: (4, 3)}


def _address(model, name: str, dof: bool):
    joint = model.joint_name2id(name)
    kind = mujoco.mjtJoint(int(model.jnt_type[joint]))
    start = (model.jnt_dofadr if dof else model.jnt_qposadr)[joint]
    if kind in WIDTH:
        return (start, start + WIDTH[kind][dof])
    return start


def _update(self, force=False):
    """robosuite's Controller.update, with MuJoCo 3.10's `mj_fullM(model, data, dst)`."""
    if self.new_update or force:
        if not (self.lite_physics and not force):
            self.sim.forward()
        if self.ref_name is not None:
            self.update_reference_data()
        self.joint_pos = np.array(self.sim.data.qpos[self.qpos_index])
        self.joint_vel = np.array(self.sim.data.qvel[self.qvel_index])
        nv = self.sim.model.nv
        mass_matrix = np.ndarray(shape=(nv, nv), dtype=np.float64, order="C")
        mujoco.mj_fullM(self.sim.model._model, self.sim.data._data, mass_matrix)
        mass_matrix = np.reshape(mass_matrix, (len(self.sim.data.qvel), len(self.sim.data.qvel)))
        self.mass_matrix = mass_matrix[self.qvel_index, :][:, self.qvel_index]
        self.new_update = False


def apply() -> None:
    binding_utils.MjModel.get_joint_qpos_addr = lambda self, name: _address(self, name, False)
    binding_utils.MjModel.get_joint_qvel_addr = lambda self, name: _address(self, name, True)
    controller.Controller.update = _update
