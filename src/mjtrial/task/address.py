"""Addresses of model elements, named or not, and labels for them.

Benchmark models leave elements unnamed (Fetch's weld, equality 0; Metaworld's hand
actuators), so wherever a task, a condition's model edits or a policy contract names an element
it may also give:

- `#<index>`: the element's index among those of its kind in the compiled model (`#0`);
- `on:<name>`: the one element of that kind attached to the named element: an actuator on a
  joint, tendon, site or body, an equality constraint on a body, joint, tendon or site, a
  sensor on its object, a geom, site, joint, camera or light on a body, a body on its parent.

`resolve` turns a name or an address into the index; `describe` labels an element for a
report or a recording: its name, else what it is attached to ("actuator 0 on joint
robot0:slide0", "weld 0 (robot0:mocap to robot0:wrist_roll_link)", "geom 1 of body
robot0:mocap").
"""

from __future__ import annotations

import mujoco

_OBJ = mujoco.mjtObj
# kind (as an MjModel accessor or MJCF element names it) -> (object type, count attribute)
KINDS: dict[str, tuple[mujoco.mjtObj, str]] = {
    "body": (_OBJ.mjOBJ_BODY, "nbody"),
    "joint": (_OBJ.mjOBJ_JOINT, "njnt"),
    "jnt": (_OBJ.mjOBJ_JOINT, "njnt"),
    "geom": (_OBJ.mjOBJ_GEOM, "ngeom"),
    "site": (_OBJ.mjOBJ_SITE, "nsite"),
    "camera": (_OBJ.mjOBJ_CAMERA, "ncam"),
    "cam": (_OBJ.mjOBJ_CAMERA, "ncam"),
    "light": (_OBJ.mjOBJ_LIGHT, "nlight"),
    "mesh": (_OBJ.mjOBJ_MESH, "nmesh"),
    "tendon": (_OBJ.mjOBJ_TENDON, "ntendon"),
    "actuator": (_OBJ.mjOBJ_ACTUATOR, "nu"),
    "sensor": (_OBJ.mjOBJ_SENSOR, "nsensor"),
    "equality": (_OBJ.mjOBJ_EQUALITY, "neq"),
    "eq": (_OBJ.mjOBJ_EQUALITY, "neq"),
}
_COUNT = {obj: count for obj, count in KINDS.values()}
# what a kind hangs from: its body (field of body ids)
_ON_BODY = {
    _OBJ.mjOBJ_GEOM: "geom_bodyid",
    _OBJ.mjOBJ_SITE: "site_bodyid",
    _OBJ.mjOBJ_JOINT: "jnt_bodyid",
    _OBJ.mjOBJ_CAMERA: "cam_bodyid",
    _OBJ.mjOBJ_LIGHT: "light_bodyid",
    _OBJ.mjOBJ_BODY: "body_parentid",
}
_TRN_OBJ = {
    mujoco.mjtTrn.mjTRN_JOINT: _OBJ.mjOBJ_JOINT,
    mujoco.mjtTrn.mjTRN_JOINTINPARENT: _OBJ.mjOBJ_JOINT,
    mujoco.mjtTrn.mjTRN_SLIDERCRANK: _OBJ.mjOBJ_SITE,
    mujoco.mjtTrn.mjTRN_TENDON: _OBJ.mjOBJ_TENDON,
    mujoco.mjtTrn.mjTRN_SITE: _OBJ.mjOBJ_SITE,
    mujoco.mjtTrn.mjTRN_BODY: _OBJ.mjOBJ_BODY,
}
_EQ_OBJ = {
    mujoco.mjtEq.mjEQ_JOINT: _OBJ.mjOBJ_JOINT,
    mujoco.mjtEq.mjEQ_TENDON: _OBJ.mjOBJ_TENDON,
}


class AddressError(ValueError):
    """A name or address that does not resolve (one line, without the file: callers add it)."""


def object_type(kind: str | mujoco.mjtObj) -> mujoco.mjtObj:
    """The `mjtObj` of a kind given as an accessor name (`"actuator"`, `"eq"`) or an mjtObj."""
    if isinstance(kind, mujoco.mjtObj):
        if kind not in _COUNT:
            raise AddressError(f"expected an element kind of {sorted(KINDS)}, got {kind.name}")
        return kind
    if kind not in KINDS:
        raise AddressError(f"expected an element kind of {sorted(KINDS)}, got {kind!r}")
    return KINDS[kind][0]


def _noun(obj: mujoco.mjtObj) -> str:
    return obj.name.removeprefix("mjOBJ_").lower()


def _a(noun: str) -> str:
    return f"an {noun}" if noun[0] in "aeiou" else f"a {noun}"


def count(model: mujoco.MjModel, kind: str | mujoco.mjtObj) -> int:
    """How many elements of the kind the model has."""
    return int(getattr(model, _COUNT[object_type(kind)]))


def _attached(model: mujoco.MjModel, obj: mujoco.mjtObj, i: int) -> list[tuple[mujoco.mjtObj, int]]:
    """The elements element i of type obj is attached to, as (type, index), of the kinds here
    (a sensor's `xbody` is its body; a flex, a plugin are left out)."""
    return [
        (_OBJ.mjOBJ_BODY if o == _OBJ.mjOBJ_XBODY else o, j)
        for o, j in _attached_any(model, obj, i)
        if o in _COUNT or o == _OBJ.mjOBJ_XBODY
    ]


def _attached_any(
    model: mujoco.MjModel, obj: mujoco.mjtObj, i: int
) -> list[tuple[mujoco.mjtObj, int]]:
    if obj in _ON_BODY:
        return [(_OBJ.mjOBJ_BODY, int(getattr(model, _ON_BODY[obj])[i]))]
    if obj == _OBJ.mjOBJ_ACTUATOR:
        trn = _TRN_OBJ.get(mujoco.mjtTrn(model.actuator_trntype[i]))
        return [] if trn is None else [(trn, int(model.actuator_trnid[i, 0]))]
    if obj == _OBJ.mjOBJ_EQUALITY:
        # eq_objtype is that of a connect's or weld's ends (body or site); 0 for the others
        of = _EQ_OBJ.get(mujoco.mjtEq(model.eq_type[i])) or _OBJ(int(model.eq_objtype[i]))
        ids = (int(model.eq_obj1id[i]), int(model.eq_obj2id[i]))
        return [(of, j) for j in ids if j >= 0]
    if obj == _OBJ.mjOBJ_SENSOR:
        of, j = int(model.sensor_objtype[i]), int(model.sensor_objid[i])
        return [] if of == _OBJ.mjOBJ_UNKNOWN or j < 0 else [(_OBJ(of), j)]
    return []


def resolve(model: mujoco.MjModel, kind: str | mujoco.mjtObj, ref: str) -> int:
    """The index of the element of `kind` that `ref` names: a name, `#<index>` or
    `on:<name>` (module docstring). Raises `AddressError` (one line: what was expected; an
    ambiguous `on:` lists the candidates' addresses)."""
    obj = object_type(kind)
    noun, n = _noun(obj), count(model, obj)
    if not isinstance(ref, str):
        raise AddressError(f"expected {_a(noun)} name, '#<index>' or 'on:<name>', got {ref!r}")
    if ref.startswith("#"):
        digits = ref[1:]
        # ASCII digits only: `str.isdigit` takes "²", which int() refuses
        if not (digits.isascii() and digits.isdecimal()) or int(digits) >= n:
            raise AddressError(
                f"expected '#<index>' with an index 0 to {n - 1} among the model's "
                f"{_count(n, noun)}, got {ref!r}"
            )
        return int(digits)
    if ref.startswith("on:"):
        target = ref[3:]
        found = [
            i
            for i in range(n)
            if any(mujoco.mj_id2name(model, o, j) == target for o, j in _attached(model, obj, i))
        ]
        if len(found) == 1:
            return found[0]
        if not found:
            raise AddressError(
                f"expected {_a(noun)} attached to an element named {target!r}, found none"
            )
        shown = "; ".join(f"#{i}: {describe(model, obj, i)}" for i in found)
        raise AddressError(
            f"{ref!r} is ambiguous: {_count(len(found), noun)} are attached to {target!r} "
            f"({shown}); expected one, or give its '#<index>'"
        )
    index = mujoco.mj_name2id(model, obj, ref)
    if index < 0:
        raise AddressError(f"expected {_a(noun)} named {ref!r} in the model")
    return index


def describe(model: mujoco.MjModel, kind: str | mujoco.mjtObj, index: int) -> str:
    """A label of element `index` of `kind`: its name, else what it is and what it is attached
    to ("geom 27 of body robot0:base_link", "actuator 7 on joint j", "weld 0 (a to b)")."""
    obj = object_type(kind)
    index = int(index)
    name = mujoco.mj_id2name(model, obj, index)
    if name:
        return name
    noun = _noun(obj)
    attached = _attached(model, obj, index)
    if obj == _OBJ.mjOBJ_EQUALITY:
        kind_name = mujoco.mjtEq(model.eq_type[index]).name.removeprefix("mjEQ_").lower()
        ends = " to ".join(describe(model, o, j) for o, j in attached)
        return f"{kind_name} {index} ({ends})" if ends else f"{kind_name} {index}"
    if obj == _OBJ.mjOBJ_SENSOR:
        kind_name = mujoco.mjtSensor(model.sensor_type[index]).name.removeprefix("mjSENS_").lower()
        on = "".join(f" on {_noun(o)} {describe(model, o, j)}" for o, j in attached)
        return f"sensor {index} ({kind_name}){on}"
    if obj == _OBJ.mjOBJ_BODY and attached:
        if index == 0:
            return "world"
        return f"body {index} (child of {describe(model, _OBJ.mjOBJ_BODY, attached[0][1])})"
    if obj in _ON_BODY and attached:
        return f"{noun} {index} of body {describe(model, _OBJ.mjOBJ_BODY, attached[0][1])}"
    if attached:
        o, j = attached[0]
        return f"{noun} {index} on {_noun(o)} {describe(model, o, j)}"
    return f"{noun} {index}"


def _count(n: int, noun: str) -> str:
    """'1 equality', '3 equalities', '2 bodies', '0 actuators'."""
    if n == 1:
        return f"1 {noun}"
    plural = noun[:-1] + "ies" if noun.endswith("y") and noun[-2] not in "aeiou" else noun + "s"
    return f"{n} {plural}"
