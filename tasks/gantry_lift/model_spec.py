"""The model's named elements, resolved once: the one place their names are spelled.

Every module that reads the simulation (the engine, the failure taxonomy, the recordings, the
report) takes indices from a `ModelSpec` instead of looking names up itself, so a model that
lacks an element fails once, at load, with a `ModelError` naming the file and the element.

The physics-state layout and what a healthy episode is are every task's: `mjtrial.sim.physics`.
"""

from __future__ import annotations

from dataclasses import dataclass

import mujoco

from mjtrial.sim.physics import FULLPHYSICS, STATE_QPOS, ModelError

from .protocol import N_CTRL

# Element names in models/gantry_gripper/gantry_gripper.xml.
CUBE = "cube"  # the cube's body, its free joint and its box geom
LIFT_JOINT = "gantry_z"  # the carriage's vertical slide
FINGER_JOINTS = ("left_finger", "right_finger")
PADS = ("left_pad", "right_pad")  # geoms
# data="found force": [found, fx, fy, fz] in the pad's contact frame, per pad
PAD_CONTACT_SENSORS = ("left_pad_cube", "right_pad_cube")
CONTACT_SENSOR_DIM = 4
CONTACT_NORMAL_AXIS = 1  # the pads face each other along world y: normal force = |F_y|
ACTUATORS = ("x", "y", "z", "gripper")  # in ctrl order (protocol.CTRL_*)


@dataclass(frozen=True)
class ModelSpec:
    """Indices of the elements the protocol, the taxonomy and the recordings use.

    Indices into the physics state are into an mjSTATE_FULLPHYSICS vector (`FULLPHYSICS`),
    indices into sensordata are into `MjData.sensordata`.
    """

    cube_body: int
    cube_qpos: int  # cube free joint in qpos: position (3), then w-x-y-z quaternion (4)
    lift_qpos: int  # carriage height joint in qpos
    lift_dof: int  # and in qvel
    finger_qpos: tuple[int, int]  # left, right finger joints in qpos
    finger_bodies: tuple[int, int]
    carriage_body: int  # the fingers' common parent
    pad_geoms: tuple[int, int]
    pad_bodies: tuple[int, int]
    pad_sensors: tuple[int, int]  # sensordata address of each pad's [found, fx, fy, fz]
    nq: int
    nstate: int

    @property
    def state_cube_position(self) -> slice:
        """The cube's position (x, y, z) in the physics state."""
        start = STATE_QPOS + self.cube_qpos
        return slice(start, start + 3)

    @property
    def state_cube_quat(self) -> slice:
        """The cube's w-x-y-z quaternion in the physics state."""
        start = STATE_QPOS + self.cube_qpos + 3
        return slice(start, start + 4)

    @property
    def state_cube_z(self) -> int:
        return STATE_QPOS + self.cube_qpos + 2

    @property
    def state_lift_z(self) -> int:
        return STATE_QPOS + self.lift_qpos

    @property
    def state_lift_vz(self) -> int:
        return STATE_QPOS + self.nq + self.lift_dof

    @property
    def state_fingers(self) -> tuple[int, int]:
        return tuple(STATE_QPOS + q for q in self.finger_qpos)  # type: ignore[return-value]

    @property
    def pad_normal_forces(self) -> tuple[int, int]:
        """sensordata index of each pad's normal force component."""
        return tuple(a + 1 + CONTACT_NORMAL_AXIS for a in self.pad_sensors)  # type: ignore[return-value]

    @property
    def pad_found(self) -> tuple[int, int]:
        """sensordata index of each pad's contact count."""
        return self.pad_sensors

    @classmethod
    def of(cls, model: mujoco.MjModel, *, source: str = "model") -> ModelSpec:
        """Resolve every named element of `model`; `source` (its file) prefixes errors."""

        def find(kind: mujoco.mjtObj, name: str) -> int:
            i = mujoco.mj_name2id(model, kind, name)
            if i < 0:
                what = kind.name.removeprefix("mjOBJ_").lower()
                raise ModelError(f"{source}: expected a {what} named {name!r}, found none")
            return int(i)

        cube = find(mujoco.mjtObj.mjOBJ_BODY, CUBE)
        jnt = int(model.body_jntadr[cube])
        if model.body_jntnum[cube] != 1 or model.jnt_type[jnt] != mujoco.mjtJoint.mjJNT_FREE:
            raise ModelError(f"{source}: body {CUBE!r}: expected exactly one free joint")
        if model.nu != N_CTRL:
            names = ", ".join(ACTUATORS)
            raise ModelError(f"{source}: expected {N_CTRL} actuators ({names}), found {model.nu}")
        for index, name in enumerate(ACTUATORS):
            if find(mujoco.mjtObj.mjOBJ_ACTUATOR, name) != index:
                raise ModelError(
                    f"{source}: actuator {name!r}: expected it at ctrl index {index} "
                    f"(order {ACTUATORS})"
                )
        if model.nkey < 1:
            raise ModelError(f"{source}: expected a home keyframe (keyframe 0), found none")
        lift = find(mujoco.mjtObj.mjOBJ_JOINT, LIFT_JOINT)
        fingers = [find(mujoco.mjtObj.mjOBJ_JOINT, j) for j in FINGER_JOINTS]
        finger_bodies = [int(model.jnt_bodyid[j]) for j in fingers]
        parents = {int(model.body_parentid[b]) for b in finger_bodies}
        if len(parents) != 1:
            raise ModelError(f"{source}: joints {FINGER_JOINTS}: expected fingers of one parent")
        pads = [find(mujoco.mjtObj.mjOBJ_GEOM, g) for g in PADS]
        sensors = []
        for name, pad in zip(PAD_CONTACT_SENSORS, pads, strict=True):
            sid = find(mujoco.mjtObj.mjOBJ_SENSOR, name)
            if (
                model.sensor_dim[sid] != CONTACT_SENSOR_DIM
                or model.sensor_objtype[sid] != mujoco.mjtObj.mjOBJ_GEOM
                or model.sensor_objid[sid] != pad
            ):
                raise ModelError(
                    f"{source}: sensor {name!r}: expected a contact sensor of geom "
                    f'{model.geom(pad).name!r} with data="found force" '
                    f"({CONTACT_SENSOR_DIM} values)"
                )
            sensors.append(int(model.sensor_adr[sid]))
        return cls(
            cube_body=cube,
            cube_qpos=int(model.jnt_qposadr[jnt]),
            lift_qpos=int(model.jnt_qposadr[lift]),
            lift_dof=int(model.jnt_dofadr[lift]),
            finger_qpos=tuple(int(model.jnt_qposadr[j]) for j in fingers),  # type: ignore[arg-type]
            finger_bodies=tuple(finger_bodies),  # type: ignore[arg-type]
            carriage_body=parents.pop(),
            pad_geoms=tuple(pads),  # type: ignore[arg-type]
            pad_bodies=tuple(int(model.geom_bodyid[g]) for g in pads),  # type: ignore[arg-type]
            pad_sensors=tuple(sensors),  # type: ignore[arg-type]
            nq=int(model.nq),
            nstate=int(mujoco.mj_stateSize(model, FULLPHYSICS)),
        )
