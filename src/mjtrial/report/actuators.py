"""What bounds each actuator of a compiled model, in the units of what it drives.

MuJoCo's actuator force is gain × input + bias, clamped to `forcerange` when it is limited, and
acts on its joint, tendon or site times `gear`. The input is the ctrl (clamped to `ctrlrange`),
or for an actuator with dynamics its activation: a state variable that `dyntype` moves towards
the ctrl (filter, filterexact, muscle) or integrates it (integrator), clamped to `actrange`.
The bias of a servo reads the actuator's length (gear × the joint's position) and velocity, so a
position servo's force is bounded by kp × (ctrlrange − the lengths the joint's range allows); a
muscle's gain and bias are MuJoCo's muscle model: peak force × force-length × force-velocity ×
activation, plus a passive force that grows with length. Everything is read from `MjModel` and
computed with MuJoCo's own muscle functions (`mju_muscleGain`, `mju_muscleBias`).
"""

from __future__ import annotations

import math

import mujoco
import numpy as np

from mjtrial.task.address import describe

_OBJ = mujoco.mjtObj
_TRN = mujoco.mjtTrn
_DYN = mujoco.mjtDyn
_GAIN = mujoco.mjtGain
_BIAS = mujoco.mjtBias
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
_UNBOUNDED = (-math.inf, math.inf)

Interval = tuple[float, float]


def _label(model: mujoco.MjModel, kind: mujoco.mjtObj, index: int) -> str:
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


def _driven_kind(model: mujoco.MjModel, i: int) -> str:
    """The kind of element actuator `i` drives: joint, tendon, site..."""
    trn = _TRN(model.actuator_trntype[i])
    return "joint" if trn == _TRN.mjTRN_JOINTINPARENT else trn.name[6:].lower()


def _stateless(model: mujoco.MjModel, i: int) -> bool:
    return _DYN(model.actuator_dyntype[i]) == _DYN.mjDYN_NONE


def _is_motor(model: mujoco.MjModel, i: int) -> bool:
    """A fixed gain and no bias: force = gain × control (or activation)."""
    return (
        _GAIN(model.actuator_gaintype[i]) == _GAIN.mjGAIN_FIXED
        and _BIAS(model.actuator_biastype[i]) == _BIAS.mjBIAS_NONE
    )


def is_muscle(model: mujoco.MjModel, i: int) -> bool:
    """MuJoCo's muscle model sets the gain (MJCF `<muscle>`, or a `<general>` so declared)."""
    return _GAIN(model.actuator_gaintype[i]) == _GAIN.mjGAIN_MUSCLE


def servo_kind(model: mujoco.MjModel, i: int) -> str | None:
    """`position` or `velocity` when actuator `i` is a servo (MJCF `<position>`, `<velocity>`:
    a fixed gain k and an affine bias -k × length (-kv × velocity too for a damped position
    servo), or -k × velocity), else None."""
    if (
        _GAIN(model.actuator_gaintype[i]) != _GAIN.mjGAIN_FIXED
        or _BIAS(model.actuator_biastype[i]) != _BIAS.mjBIAS_AFFINE
        or not _stateless(model, i)
    ):
        return None
    gain, bias = model.actuator_gainprm[i, 0], model.actuator_biasprm[i, :3]
    if gain > 0 and bias[0] == 0 and bias[1] == -gain:
        return "position"
    if gain > 0 and bias[0] == 0 and bias[1] == 0 and bias[2] == -gain:
        return "velocity"
    return None


def initial_activation(model: mujoco.MjModel, i: int, keyframe: int | None = None) -> float:
    """The activation actuator `i` starts from after the reset: the keyframe's `act`, else 0
    (`mj_resetData`). A task's `episode_setup` may change it."""
    adr = model.actuator_actadr[i]
    if adr < 0:
        return 0.0
    return float(model.key_act[keyframe, adr]) if keyframe is not None else 0.0


def _input_range(model: mujoco.MjModel, i: int, act0: float) -> tuple[Interval, str]:
    """The range of what multiplies the gain: the ctrl, or the activation; and what sets it."""
    ctrl = tuple(model.actuator_ctrlrange[i]) if model.actuator_ctrllimited[i] else None
    dyn = _DYN(model.actuator_dyntype[i])
    if dyn == _DYN.mjDYN_NONE:
        return (ctrl, "ctrlrange") if ctrl else (_UNBOUNDED, "no ctrlrange")
    if model.actuator_actlimited[i]:
        return tuple(model.actuator_actrange[i]), "actrange"
    if dyn == _DYN.mjDYN_MUSCLE:  # MuJoCo clamps the ctrl to [0, 1] and moves act towards it
        return (min(0.0, act0), max(1.0, act0)), "activation in [0, 1]"
    if dyn in (_DYN.mjDYN_FILTER, _DYN.mjDYN_FILTEREXACT) and ctrl:
        # a first-order filter stays between its start and the ctrls it follows
        return (min(ctrl[0], act0), max(ctrl[1], act0)), "activation within ctrlrange"
    return _UNBOUNDED, "activation without actrange"


def length_range(model: mujoco.MjModel, i: int) -> tuple[Interval, str] | None:
    """The lengths actuator `i` can have (gear × its joint's or tendon's position) when its
    joint or tendon is limited, else the `lengthrange` MuJoCo's compiler computed (muscles);
    None when nothing bounds it. A limit is soft: a joint pushed past it goes a little further."""
    trn, target = _TRN(model.actuator_trntype[i]), model.actuator_trnid[i, 0]
    gear = model.actuator_gear[i, 0]
    limited = None
    if trn in (_TRN.mjTRN_JOINT, _TRN.mjTRN_JOINTINPARENT) and model.jnt_limited[target]:
        kind = mujoco.mjtJoint(model.jnt_type[target])
        if kind in (mujoco.mjtJoint.mjJNT_HINGE, mujoco.mjtJoint.mjJNT_SLIDE):
            limited = model.jnt_range[target], "the joint's range"
    elif trn == _TRN.mjTRN_TENDON and model.tendon_limited[target]:
        limited = model.tendon_range[target], "the tendon's range"
    if limited is not None:
        ends = sorted(gear * float(v) for v in limited[0])
        return (ends[0], ends[1]), limited[1]
    low, high = (float(v) for v in model.actuator_lengthrange[i])
    if low < high:
        return (low, high), "its lengthrange"
    return None


def _times(k: float, interval: Interval) -> Interval:
    if k == 0:
        return (0.0, 0.0)
    ends = sorted(k * v for v in interval)
    return ends[0], ends[1]


def _plus(a: Interval, b: Interval) -> Interval:
    return a[0] + b[0], a[1] + b[1]


def peak_muscle_force(model: mujoco.MjModel, i: int) -> float:
    """A muscle's peak active force F0 (N at the tendon, before gear): its `force`, or when
    that is negative (MJCF's default -1) `scale` / acc0, as MuJoCo computes it."""
    force, scale = model.actuator_gainprm[i, 2], model.actuator_gainprm[i, 3]
    return float(force) if force > 0 else float(scale / model.actuator_acc0[i])


def _muscle_force(model: mujoco.MjModel, i: int, act: Interval) -> tuple[Interval, str]:
    """The range of a muscle's force (always pulling: <= 0): -(F0 × force-length (<= 1) ×
    force-velocity (<= fvmax) × activation + F0 × passive(length))."""
    prm = model.actuator_gainprm[i, :9]
    f0, fvmax = peak_muscle_force(model, i), float(prm[8])
    active = (-f0 * fvmax * max(act[1], 0.0), 0.0)
    if _BIAS(model.actuator_biastype[i]) != _BIAS.mjBIAS_MUSCLE:
        return active, f"peak force {f0:g} N × force-velocity up to fvmax {fvmax:g} × activation"
    lengths = model.actuator_lengthrange[i]
    if not lengths[0] < lengths[1]:
        return (-math.inf, 0.0), "passive force unbounded (no lengthrange)"
    passive = mujoco.mju_muscleBias(
        float(lengths[1]), lengths, float(model.actuator_acc0[i]), model.actuator_biasprm[i, :9]
    )
    why = (
        f"peak force {f0:g} N × force-velocity up to fvmax {fvmax:g} × activation {act[1]:g}, "
        f"plus the passive force, {-passive:g} N at the longest length of its lengthrange"
    )
    return (active[0] + passive, 0.0), why


def _unclamped_force(model: mujoco.MjModel, i: int, act0: float) -> tuple[Interval, str]:
    """The range of gain × input + bias before `forcerange`, and what sets it (words)."""
    u, u_source = _input_range(model, i, act0)
    if is_muscle(model, i):
        return _muscle_force(model, i, u)
    if _GAIN(model.actuator_gaintype[i]) != _GAIN.mjGAIN_FIXED:
        return _UNBOUNDED, "a gain that depends on length or velocity"
    gain = float(model.actuator_gainprm[i, 0])
    force = _times(gain, u)
    if not all(map(math.isfinite, force)):
        return _UNBOUNDED, u_source
    bias_type = _BIAS(model.actuator_biastype[i])
    if bias_type == _BIAS.mjBIAS_NONE:
        return force, f"{u_source} × gain"
    if bias_type != _BIAS.mjBIAS_AFFINE:
        return _UNBOUNDED, "a muscle or user bias"
    b0, b1, b2 = (float(b) for b in model.actuator_biasprm[i, :3])
    if b2:
        return _UNBOUNDED, "its bias has a velocity term, and the velocity has no bound"
    force, words = _plus(force, (b0, b0)), f"gain × {u_source} + bias"
    if b1:
        lengths = length_range(model, i)
        if lengths is None:
            return _UNBOUNDED, "its bias reads its length, which no joint or tendon range bounds"
        force = _plus(force, _times(b1, lengths[0]))
        gear = model.actuator_gear[i, 0]
        over = lengths[1] if gear == 1 else f"gear × {lengths[1]}"
        words = (
            f"kp × ({u_source} − {over})"
            if servo_kind(model, i) == "position"
            else f"{words} over {over}"
        )
    return force, words


def actuator_force_limit(
    model: mujoco.MjModel, i: int, *, keyframe: int | None = None
) -> tuple[float, float, str] | None:
    """The bounds of actuator `i`'s force where it acts (gear × the actuator's force), and what
    sets them (its control or activation range through its gain and bias, its `forcerange`);
    None when nothing bounds it."""
    force, source = _unclamped_force(model, i, initial_activation(model, i, keyframe))
    sources = [source] if all(map(math.isfinite, force)) else []
    if model.actuator_forcelimited[i]:
        low, high = (float(v) for v in model.actuator_forcerange[i])
        if low > force[0] or high < force[1]:
            sources.append("forcerange")
            force = (max(force[0], low), min(force[1], high))
    if not all(map(math.isfinite, force)):
        return None
    gear = model.actuator_gear[i, 0]
    ends = sorted((gear * force[0] + 0.0, gear * force[1] + 0.0))  # + 0.0: no -0 in the report
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


def _servo_text(model: mujoco.MjModel, i: int, kind: str, force_unit: str, unit: str) -> str:
    """A servo's target range and gain (at the joint: gain × gear²)."""
    gear = model.actuator_gear[i, 0]
    over_gear = f" / gear {gear:g}" if gear != 1 else ""
    unit = unit if kind == "position" else f"{unit}/s"
    target = servo_target_range(model, i)
    gain = model.actuator_gainprm[i, 0]
    gain_unit = f"{force_unit}/{unit}" if force_unit and unit else ""
    where = (
        f"target [{target[0]:g}, {target[1]:g}] {unit} (ctrlrange{over_gear})"
        if target
        else "target unbounded (no ctrlrange)"
    )
    gain_name = "kp" if kind == "position" else "kv"
    stiffness = (
        f"{gain_name} {gain:g} {gain_unit}"
        if gear == 1
        else f"{gain_name} {gain:g} ({gain * gear**2:g} {gain_unit} at the "
        f"{_driven_kind(model, i)}: {gain_name} × gear²)"
    )
    damping = -model.actuator_biasprm[i, 2] if kind == "position" else 0.0
    damped = f", kv {damping:g} (damping)" if damping else ""
    return f"{kind} servo, {where}, {stiffness}".rstrip() + damped


def _muscle_text(model: mujoco.MjModel, i: int) -> str:
    """A muscle's parameters as MJCF names them."""
    prm = model.actuator_gainprm[i, :9]
    f0 = peak_muscle_force(model, i)
    peak = (
        f"`force` {f0:g} N"
        if prm[2] > 0
        else f"`scale` {prm[3]:g} / acc0 {model.actuator_acc0[i]:.4g} = {f0:.4g} N"
    )
    return (
        f"muscle, peak force {peak} at optimal length; force-length zero outside "
        f"[{prm[4]:g}, {prm[5]:g}] of the optimal length (`lmin`, `lmax`; `range` "
        f"[{prm[0]:g}, {prm[1]:g}] of it over the lengthrange), force-velocity up to "
        f"`fvmax` {prm[8]:g} (`vmax` {prm[6]:g} optimal lengths/s), passive force zero up to "
        f"optimal length, {passive_at_lmax(prm):.3g} × peak at `lmax` (`fpmax` {prm[7]:g}) and "
        "growing beyond"
    )


def passive_at_lmax(prm: np.ndarray) -> float:
    """A muscle's passive force at `lmax`, in peak forces: MuJoCo's own curve
    (`mju_muscleBias`), on a unit lengthrange mapped onto the muscle's `range`."""
    unit = np.array(prm[:9], dtype=np.float64)
    unit[2] = 1.0  # a peak force of 1
    lengths = np.array([0.0, 1.0])
    at_lmax = (unit[5] - unit[0]) / (unit[1] - unit[0])  # lmax on that lengthrange
    return -mujoco.mju_muscleBias(at_lmax, lengths, 1.0, unit)


_DYN_WORDS = {
    _DYN.mjDYN_INTEGRATOR: "integrator (the activation's rate is the ctrl)",
    _DYN.mjDYN_FILTER: "filter (first order, towards the ctrl)",
    _DYN.mjDYN_FILTEREXACT: "filterexact (first order, towards the ctrl, integrated exactly)",
    _DYN.mjDYN_MUSCLE: "muscle (towards the ctrl clamped to [0, 1])",
    _DYN.mjDYN_USER: "user (`mjcb_act_dyn`)",
}


def activation_text(model: mujoco.MjModel, i: int, keyframe: int | None = None) -> str:
    """An actuator with dynamics: its `dyntype`, time constants, `actrange`, and its activation
    as part of the state with its starting value; "" for a stateless actuator."""
    dyn = _DYN(model.actuator_dyntype[i])
    if dyn == _DYN.mjDYN_NONE:
        return ""
    prm = model.actuator_dynprm[i]
    words = [f"activation dynamics {_DYN_WORDS.get(dyn, dyn.name[6:].lower())}"]
    if dyn == _DYN.mjDYN_MUSCLE:
        words.append(
            f"time constants {prm[0] * 1e3:g} ms activating, {prm[1] * 1e3:g} ms deactivating "
            "(`timeconst`, scaled by the activation as MuJoCo's muscle model does)"
        )
    elif dyn in (_DYN.mjDYN_FILTER, _DYN.mjDYN_FILTEREXACT):
        words.append(f"time constant {prm[0] * 1e3:g} ms (`timeconst`)")
    if model.actuator_ctrllimited[i]:
        low, high = model.actuator_ctrlrange[i]
        words.append(f"ctrl in `ctrlrange` [{low:g}, {high:g}]")
    if model.actuator_actlimited[i]:
        low, high = model.actuator_actrange[i]
        words.append(f"activation clamped to `actrange` [{low:g}, {high:g}]")
    if model.actuator_actearly[i]:
        words.append("the force uses the next step's activation (`actearly`)")
    start = initial_activation(model, i, keyframe)
    origin = "the keyframe's `act`" if keyframe is not None else "MuJoCo's reset"
    words.append(
        f"the activation is part of the state: each episode starts from its initial state's "
        f"({start:g} after {origin}, before any `episode_setup`)"
    )
    return ", ".join(words)


def _stop_text(model: mujoco.MjModel, i: int, position_unit: str) -> str:
    """What stops the joint or tendon the actuator drives: its range, a soft limit."""
    trn, target = _TRN(model.actuator_trntype[i]), model.actuator_trnid[i, 0]
    if trn in (_TRN.mjTRN_JOINT, _TRN.mjTRN_JOINTINPARENT) and model.jnt_limited[target]:
        low, high = model.jnt_range[target]
        return f"the joint's range [{low:g}, {high:g}] {position_unit} stops it (a soft limit)"
    if trn == _TRN.mjTRN_TENDON and model.tendon_limited[target]:
        low, high = model.tendon_range[target]
        return f"the tendon's range [{low:g}, {high:g}] m stops it (a soft limit)"
    if trn == _TRN.mjTRN_TENDON:  # a fixed tendon's joints may be limited one by one
        first, n = model.tendon_adr[target], model.tendon_num[target]
        joints = [
            int(model.wrap_objid[w])
            for w in range(first, first + n)
            if model.wrap_type[w] == mujoco.mjtWrap.mjWRAP_JOINT
            and model.jnt_limited[model.wrap_objid[w]]
        ]
        if joints:
            unit = lambda j: _JOINT_POSITION_UNIT[mujoco.mjtJoint(model.jnt_type[j])]  # noqa: E731
            ranges = ", ".join(
                f"`{_label(model, _OBJ.mjOBJ_JOINT, j)}` [{model.jnt_range[j][0]:g}, "
                f"{model.jnt_range[j][1]:g}] {unit(j)}"
                for j in joints
            )
            return f"its joints' ranges stop it (soft limits): {ranges}"
    return ""


def _unbounded_text(model: mujoco.MjModel, i: int, source: str) -> str:
    """Why nothing bounds an actuator's force, in words."""
    if _is_motor(model, i) and _stateless(model, i):
        return "force unbounded (no forcerange, no control range)"
    return f"force unbounded (no forcerange; {source})"


def _bound_text(
    model: mujoco.MjModel, i: int, force_unit: str, position_unit: str, keyframe: int | None
) -> str:
    """What bounds actuator `i`: what kind it is, its force's bounds, its activation, and what
    stops what it drives."""
    parts = []
    kind = servo_kind(model, i)
    if kind is not None:
        parts.append(_servo_text(model, i, kind, force_unit, position_unit))
    elif is_muscle(model, i):
        parts.append(_muscle_text(model, i))
    elif not _is_motor(model, i):
        gain, bias = (
            _GAIN(model.actuator_gaintype[i]).name[7:].lower(),
            _BIAS(model.actuator_biastype[i]).name[7:].lower(),
        )
        parts.append(f"general actuator, {gain} gain, {bias} bias")
    limit = actuator_force_limit(model, i, keyframe=keyframe)
    if limit is not None:
        parts.append(f"force [{limit[0]:g}, {limit[1]:g}] {force_unit} ({limit[2]})")
    else:
        _, source = _unclamped_force(model, i, initial_activation(model, i, keyframe))
        parts.append(_unbounded_text(model, i, source))
    extra = (activation_text(model, i, keyframe), _stop_text(model, i, position_unit))
    parts += [t for t in extra if t]
    return "; ".join(parts)


def actuator_lines(model: mujoco.MjModel, *, keyframe: int | None = None) -> list[str]:
    """One line per actuator: what it drives, what kind it is and what bounds its force there
    (in that joint's, tendon's or site's units), its activation, and what stops what it
    drives. `keyframe`: the task's reset keyframe (an activation's starting value)."""
    if model.nu == 0:
        return ["- Actuators: none."]
    lines = ["- Actuators, what bounds each where it acts (from the compiled model):"]
    for i in range(model.nu):
        driven, force_unit, position_unit = _driven(model, i)
        bound = _bound_text(model, i, force_unit, position_unit, keyframe)
        named = mujoco.mj_id2name(model, _OBJ.mjOBJ_ACTUATOR, i)
        label = f"`{named}`" if named else f"actuator {i}"  # "on ..." follows either way
        lines.append(f"  - {label} on {driven}: {bound}")
    return lines
