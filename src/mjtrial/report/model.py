"""What the report says of a compiled model: only what is true of any model.

Actuator limits in the units of what they drive, the equality constraints (a mocap weld), what
a policy's output columns drive (mocap targets too), the geom pairs MuJoCo's collision filter
lets through (none when contacts are disabled), and the joints' damping, armature and
frictionloss: read from the compiled `MjModel`, never assumed from the built-in tasks.
"""

from __future__ import annotations

import mujoco
import numpy as np

from mjtrial.actuation import Actuation, ControlColumn
from mjtrial.contacts import (  # noqa: F401 - the report's contact lines, said where they live
    collision_pairs,
    contact_lines,
    contacts_enabled,
)
from mjtrial.task.address import describe

_OBJ = mujoco.mjtObj
_TRN = mujoco.mjtTrn
# what a unit of generalized force is on each joint type
_JOINT_FORCE_UNIT = {
    mujoco.mjtJoint.mjJNT_SLIDE: "N",
    mujoco.mjtJoint.mjJNT_HINGE: "N·m",
    mujoco.mjtJoint.mjJNT_BALL: "N·m",
    mujoco.mjtJoint.mjJNT_FREE: "N, N·m",
}
# what a unit of position is on each joint type
_JOINT_POSITION_UNIT = {
    mujoco.mjtJoint.mjJNT_SLIDE: "m",
    mujoco.mjtJoint.mjJNT_HINGE: "rad",
    mujoco.mjtJoint.mjJNT_BALL: "rad",
    mujoco.mjtJoint.mjJNT_FREE: "m, rad",
}


def _label(model: mujoco.MjModel, kind: mujoco.mjtObj, index: int) -> str:
    """How the report names element `index` of `kind`: its name, else what it is attached to
    ("geom 27 of body robot0:base_link", `mjtrial.task.address.describe`)."""
    return describe(model, kind, index)


def _driven(model: mujoco.MjModel, i: int) -> tuple[str, str, str]:
    """What actuator `i` drives, the unit of its force there and the unit of its position."""
    trn, target = _TRN(model.actuator_trntype[i]), model.actuator_trnid[i, 0]
    if trn in (_TRN.mjTRN_JOINT, _TRN.mjTRN_JOINTINPARENT):
        kind = mujoco.mjtJoint(model.jnt_type[target])
        return (
            f"joint `{_label(model, _OBJ.mjOBJ_JOINT, target)}`",
            _JOINT_FORCE_UNIT[kind],
            _JOINT_POSITION_UNIT[kind],
        )
    if trn == _TRN.mjTRN_TENDON:
        return f"tendon `{_label(model, _OBJ.mjOBJ_TENDON, target)}`", "N", "m"
    if trn == _TRN.mjTRN_SITE:
        return f"site `{_label(model, _OBJ.mjOBJ_SITE, target)}`", "N, N·m", "m, rad"
    return trn.name[6:].lower(), "", ""


def _is_motor(model: mujoco.MjModel, i: int) -> bool:
    """A fixed gain and no bias: force = gain × control (or activation)."""
    return (
        mujoco.mjtGain(model.actuator_gaintype[i]) == mujoco.mjtGain.mjGAIN_FIXED
        and mujoco.mjtBias(model.actuator_biastype[i]) == mujoco.mjtBias.mjBIAS_NONE
    )


def servo_kind(model: mujoco.MjModel, i: int) -> str | None:
    """`position` or `velocity` when actuator `i` is a servo (MJCF `<position>`, `<velocity>`:
    a fixed gain k and an affine bias -k × length, or -k × velocity), else None."""
    if (
        mujoco.mjtGain(model.actuator_gaintype[i]) != mujoco.mjtGain.mjGAIN_FIXED
        or mujoco.mjtBias(model.actuator_biastype[i]) != mujoco.mjtBias.mjBIAS_AFFINE
        or mujoco.mjtDyn(model.actuator_dyntype[i]) != mujoco.mjtDyn.mjDYN_NONE
    ):
        return None
    gain, bias = model.actuator_gainprm[i, 0], model.actuator_biasprm[i, :3]
    if gain > 0 and bias[0] == 0 and bias[1] == -gain:
        return "position"
    if gain > 0 and bias[0] == 0 and bias[1] == 0 and bias[2] == -gain:
        return "velocity"
    return None


def actuator_force_limit(model: mujoco.MjModel, i: int) -> tuple[float, float, str] | None:
    """The bounds of actuator `i`'s force where it acts (gear times the actuator's force), and
    what sets them: its `forcerange`, or for a motor (a fixed gain, no bias) its control or
    activation range times its gain; None when nothing bounds it (a servo without a `forcerange`
    pushes as hard as its error asks)."""
    gear = model.actuator_gear[i, 0]
    bounds: list[tuple[float, float]] = []
    sources = []
    if _is_motor(model, i):
        stateful = mujoco.mjtDyn(model.actuator_dyntype[i]) != mujoco.mjtDyn.mjDYN_NONE
        if stateful and model.actuator_actlimited[i]:
            bounds.append(tuple(model.actuator_gainprm[i, 0] * model.actuator_actrange[i]))
            sources.append("actrange × gain")
        elif model.actuator_ctrllimited[i]:
            bounds.append(tuple(model.actuator_gainprm[i, 0] * model.actuator_ctrlrange[i]))
            sources.append("ctrlrange × gain")
    if model.actuator_forcelimited[i]:
        bounds.append(tuple(model.actuator_forcerange[i]))
        sources.append("forcerange")
    if not bounds:
        return None
    low = max(min(b) for b in bounds)
    high = min(max(b) for b in bounds)
    ends = sorted((gear * low + 0.0, gear * high + 0.0))  # + 0.0: no -0 in the report
    return ends[0], ends[1], " and ".join(sources) + (f", × gear {gear:g}" if gear != 1 else "")


def servo_target_range(model: mujoco.MjModel, i: int) -> tuple[float, float] | None:
    """The range of a servo's target in the units of what it drives (the joint's position, or
    velocity): its `ctrlrange` divided by its gear (the servo compares the control with gear ×
    the joint's position); None when it is not a servo or its control is not limited."""
    gear = model.actuator_gear[i, 0]
    if servo_kind(model, i) is None or not model.actuator_ctrllimited[i] or gear == 0:
        return None
    ends = sorted(float(c) / gear + 0.0 for c in model.actuator_ctrlrange[i])
    return ends[0], ends[1]


def _driven_kind(model: mujoco.MjModel, i: int) -> str:
    """The kind of element actuator `i` drives: joint, tendon, site..."""
    trn = _TRN(model.actuator_trntype[i])
    return "joint" if trn == _TRN.mjTRN_JOINTINPARENT else trn.name[6:].lower()


def _bound_text(model: mujoco.MjModel, i: int, force_unit: str, position_unit: str) -> str:
    """What bounds actuator `i`: a servo's target range and gain, then its force's bounds."""
    limit = actuator_force_limit(model, i)
    kind = servo_kind(model, i)
    gear = model.actuator_gear[i, 0]
    over_gear = f" / gear {gear:g}" if gear != 1 else ""
    parts = []
    if kind is not None:
        unit = position_unit if kind == "position" else f"{position_unit}/s"
        target = servo_target_range(model, i)
        gain = model.actuator_gainprm[i, 0]
        gain_unit = f"{force_unit}/{unit}" if force_unit and unit else ""
        where = (
            f"target [{target[0]:g}, {target[1]:g}] {unit} (ctrlrange{over_gear})"
            if target
            else "target unbounded (no ctrlrange)"
        )
        gain_name = "kp" if kind == "position" else "kv"
        # at the joint the servo's force is gear × gain × (control - gear × position)
        stiffness = (
            f"{gain_name} {gain:g} {gain_unit}"
            if gear == 1
            else f"{gain_name} {gain:g} ({gain * gear**2:g} {gain_unit} at the "
            f"{_driven_kind(model, i)}: {gain_name} × gear²)"
        )
        parts.append(f"{kind} servo, {where}, {stiffness}".rstrip())
    if limit is not None:
        parts.append(f"force [{limit[0]:g}, {limit[1]:g}] {force_unit} ({limit[2]})")
    elif kind is not None:
        parts.append(f"force unbounded (no forcerange: {gain_name} × the error, however large)")
    elif _is_motor(model, i):
        parts.append("force unbounded (no forcerange, no control range)")
    else:
        parts.append("force unbounded (no forcerange)")
    return "; ".join(parts)


def actuator_lines(model: mujoco.MjModel) -> list[str]:
    """One line per actuator: what it drives and what bounds it there (a servo's target range,
    its force's bounds), in that joint's (or tendon's, or site's) units."""
    if model.nu == 0:
        return ["- Actuators: none."]
    lines = ["- Actuators, what bounds each where it acts (from the compiled model):"]
    for i in range(model.nu):
        driven, force_unit, position_unit = _driven(model, i)
        bound = _bound_text(model, i, force_unit, position_unit)
        named = mujoco.mj_id2name(model, _OBJ.mjOBJ_ACTUATOR, i)
        label = f"`{named}`" if named else f"actuator {i}"  # "on ..." follows either way
        lines.append(f"  - {label} on {driven}: {bound}")
    return lines


def joint_lines(model: mujoco.MjModel) -> list[str]:
    """Damping, armature and frictionloss of every joint that has any (per degree of freedom:
    a joint with several lists its first), and a word on the others."""
    rows = []
    for j in range(model.njnt):
        dof = model.jnt_dofadr[j]
        values = (model.dof_damping[dof], model.dof_armature[dof], model.dof_frictionloss[dof])
        if any(values):
            kind = mujoco.mjtJoint(model.jnt_type[j]).name[6:].lower()
            rows.append(
                f"| `{_label(model, _OBJ.mjOBJ_JOINT, j)}` | {kind} | "
                + " | ".join(f"{v:g}" for v in values)
                + " |"
            )
    if not rows:
        return ["- Joints: no damping, armature or frictionloss on any joint."]
    others = model.njnt - len(rows)
    return [
        "- Joints with damping, armature or frictionloss (the joint's force units: N·s/m or "
        "N·m·s/rad, kg or kg·m², N or N·m)"
        + {0: ":", 1: "; the other joint has none:"}.get(
            others, f"; the other {others} have none:"
        ),
        "",
        "| joint | type | damping | armature | frictionloss |",
        "| --- | --- | --- | --- | --- |",
        *rows,
        "",
    ]


def model_files_text(files: dict[str, str] | None) -> str:
    """How many files the model's sha256 is over (`provenance.model_sha256`)."""
    n = len(files or {})
    return (
        "of its one file's name and bytes"
        if n == 1
        else f"over its {n} files (the scene and every file it includes or loads: names and "
        "bytes; not the `sha256sum` of the scene)"
    )


def equality_lines(model: mujoco.MjModel) -> list[str]:
    """One line per equality constraint (a mocap weld moves an arm): what it binds, whether it
    is active at the start, and its solref (how stiff it is)."""
    if model.neq == 0:
        return []
    lines = ["- Equality constraints (from the compiled model):"]
    for i in range(model.neq):
        state = "active" if model.eq_active0[i] else "inactive at the start"
        solref = ", ".join(f"{v:g}" for v in model.eq_solref[i])
        lines.append(f"  - {_label(model, _OBJ.mjOBJ_EQUALITY, i)}: {state}, solref {solref}")
    return lines


def action_lines(model: mujoco.MjModel, actuation: Actuation | None) -> list[str]:
    """What each of a closed-loop policy's output columns drives (`mjtrial.actuation`), as bound
    to the model; none when the outputs are every actuator's ctrl in order."""
    if actuation is None or actuation.passthrough:
        return []
    lines = ["- The policy's output columns, in order:"]
    for c in sorted([*actuation.controls, *actuation.mocaps], key=lambda c: c.column):
        if isinstance(c, ControlColumn):
            names = ", ".join(f"`{_label(model, _OBJ.mjOBJ_ACTUATOR, a)}`" for a in c.actuators)
            value = f"{c.scale:g} × the value"
            rule = f"its joint's position + {value}" if c.qpos is not None else value
            lines.append(f"  - column {c.column}: the ctrl of {names} = {rule}")
            continue
        body = int(np.flatnonzero(model.body_mocapid == c.mocap)[0])
        step = f"{c.scale:g} × the values"
        if c.max_step is not None:
            step += f", each axis clipped to ±{c.max_step:g} m per control step"
        reference = {
            "absolute": "",
            "target": "the previous target + ",
            "body": f"the pose of `{_label(model, _OBJ.mjOBJ_BODY, c.welded)}` as the last "
            "physics step left it + ",
        }[c.relative_to]
        rule = f"{reference}{step}"
        if c.low is not None:
            rule += f", then clipped to the box {_vec(c.low)}..{_vec(c.high)} m"
        if c.orientation is not None:
            rule += f"; orientation fixed at {_vec(c.orientation)} (w, x, y, z)"
        elif c.orientation_offset is not None:
            rule += f"; orientation that body's + {_vec(c.orientation_offset)}, normalized"
        lines.append(
            f"  - columns {c.column}-{c.column + 2}: the target position of mocap body "
            f"`{_label(model, _OBJ.mjOBJ_BODY, body)}` = {rule}"
        )
    return lines


def _vec(values) -> str:
    return "(" + ", ".join(f"{float(v):g}" for v in values) + ")"
