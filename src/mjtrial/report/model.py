"""What the report says of a compiled model: only what is true of any model.

The equality constraints (a mocap weld), what a policy's output columns drive (mocap targets
too), the geom pairs MuJoCo's collision filter lets through (none when contacts are disabled),
and the joints' damping, armature and frictionloss: read from the compiled `MjModel`, never
assumed from the built-in tasks. What bounds each actuator is `mjtrial.report.actuators`.
"""

from __future__ import annotations

import mujoco
import numpy as np

from mjtrial.sim.actuation import Actuation, ControlColumn
from mjtrial.sim.contacts import (  # noqa: F401 - the report's contact lines, said where they live
    collision_pairs,
    contact_lines,
    contacts_enabled,
)
from mjtrial.task.address import describe

_OBJ = mujoco.mjtObj


def _label(model: mujoco.MjModel, kind: mujoco.mjtObj, index: int) -> str:
    """How the report names element `index` of `kind`: its name, else what it is attached to
    ("geom 27 of body robot0:base_link", `mjtrial.task.address.describe`)."""
    return describe(model, kind, index)


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


def equality_lines(model: mujoco.MjModel, *, after_setup: bool = False) -> list[str]:
    """One line per equality constraint (a mocap weld moves an arm): what it binds, whether it
    is active at the start, its solref (how stiff it is), and for a weld what it holds the two
    bodies to: the relative pose (position, quaternion w, x, y, z), the anchor and the torque
    scale (`eq_data`). `model` is what acts at the nominal episode's start: after the task's
    `episode_setup` (`after_setup`), which may set them (Metaworld's Sawyer resets its weld)."""
    if model.neq == 0:
        return []
    of = "the nominal episode's model, after the task's `episode_setup`"
    lines = [f"- Equality constraints ({of if after_setup else 'from the compiled model'}):"]
    for i in range(model.neq):
        state = "active" if model.eq_active0[i] else "inactive at the start"
        solref = ", ".join(f"{v:g}" for v in model.eq_solref[i])
        line = f"  - {_label(model, _OBJ.mjOBJ_EQUALITY, i)}: {state}, solref {solref}"
        if model.eq_type[i] == mujoco.mjtEq.mjEQ_WELD:
            data = model.eq_data[i]  # anchor (3), relative position (3), quaternion (4), scale
            line += (
                f", relative pose {_vec(data[3:6])} m and {_vec(data[6:10])} (w, x, y, z), "
                f"anchor {_vec(data[0:3])} m, torque scale {data[10]:g}"
            )
        lines.append(line)
    return lines


def action_lines(
    model: mujoco.MjModel,
    actuation: Actuation | None,
    *,
    title: str = "- The policy's output columns, in order:",
) -> list[str]:
    """What each of a closed-loop policy's output columns drives (`mjtrial.sim.actuation`), as bound
    to the model, under `title`; none when the outputs are every actuator's ctrl in order."""
    if actuation is None or actuation.passthrough:
        return []
    lines = [title]
    for c in sorted([*actuation.controls, *actuation.mocaps], key=lambda c: c.column):
        if isinstance(c, ControlColumn):
            rules = []
            for sign in (1, -1):
                driven = [a for j, a in enumerate(c.actuators) if c.sign(j) == sign]
                if not driven:
                    continue
                names = ", ".join(f"`{_label(model, _OBJ.mjOBJ_ACTUATOR, a)}`" for a in driven)
                value = f"{c.scale:g} × the value"
                if c.qpos is not None:
                    rule = f"its joint's position {'+' if sign == 1 else '−'} {value}"
                else:
                    rule = value if sign == 1 else f"−{value}"
                rules.append(f"the ctrl of {names} = {rule}")
            lines.append(f"  - column {c.column}: {'; '.join(rules)}")
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
