"""Simulator variants: the committed model with a few attributes changed through `mujoco.MjSpec`.

A variant is a mapping of overrides, each naming an attribute by its MJCF name:

    {"option": {"timestep": 0.001, "integrator": "RK4", "cone": "pyramidal"},
     "geom": {"floor": {"friction": [0.6, 0.003, 0.0001]}},
     "actuator": {"motor": {"forcerange": [-15, 15]}},
     "body": {"arm": {"gravcomp": 0.5}},
     "joint": {"hinge": {"frictionloss": 0.2}}}

(also `tendon`, `equality`, `sensor` and `site` attributes by element name), and a default
class's values, by class name (`main` is the top one) and the kind of element it sets:

    {"default": {"main": {"joint": {"damping": [0.03, 0, 0]}, "actuator": {"gear": [...]}}}}

MuJoCo applies a class when it parses the file: MjSpec holds each element's values already
resolved, and an edit of `spec.find_default(name)` after parsing reaches no element (measured,
MuJoCo 3.14). So an edit of a class is applied as the same edit of the file's text would be:
to the class, to the classes nested in it that inherit the value, and to every element of those
classes whose value is the class's (one that sets the same value itself cannot be told apart,
and changes with it).

MuJoCo's own editing API applies them (no XML text is edited), the edited spec is compiled as
it is, and the edited model is recorded as the sha256 of that compiled model
(`physics.compiled_sha256`, its MJB bytes): the very model that runs, so "what was held fixed" is
exact for each variant, and a function of the model's files and the edits alone.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from numbers import Integral, Real
from pathlib import Path
from typing import Any
from xml.etree import ElementTree

import mujoco
import numpy as np

from mjtrial.sim.physics import ModelError, compiled_sha256, load_spec
from mjtrial.task import address

OVERRIDE_KINDS = (
    *("option", "geom", "actuator", "body"),
    *("joint", "tendon", "equality", "sensor", "site", "default"),
)
# What a default class may set, with the spec's list of the elements of that kind.
DEFAULT_ELEMENTS = {
    "joint": "joints",
    "geom": "geoms",
    "site": "sites",
    "tendon": "tendons",
    "actuator": "actuators",
    "equality": "equalities",
}

# The spec's list of each kind of element an override may name (in the compiled model's order).
SPEC_ELEMENTS = {
    **DEFAULT_ELEMENTS,
    "body": "bodies",
    "sensor": "sensors",
}

# MJCF's keywords for the enumerated <option> attributes, in the order of their mjt enums
# (mjtIntegrator, mjtCone, mjtSolver, mjtJacobian); MjSpec stores the enum's integer.
OPTION_KEYWORDS: dict[str, tuple[str, ...]] = {
    "integrator": ("Euler", "RK4", "implicit", "implicitfast"),
    "cone": ("pyramidal", "elliptic"),
    "solver": ("PGS", "CG", "Newton"),
    "jacobian": ("dense", "sparse", "auto"),
}
# Bit fields (MJCF's <flag> element and actuator groups), not single values: not overridable.
_OPTION_BITFIELDS = ("disableflags", "enableflags", "disableactuator")
# Attributes MjSpec holds but a variant must not set: identity, and a body's inertial values,
# which the compiler ignores while it infers inertia from the geoms (change a geom's mass).
_NOT_SETTABLE = ("id", "signature", "mass", "inertia", "fullinertia", "ipos", "iquat")
POSITIVE_OPTIONS = ("timestep", "impratio")


def _fail(key: str, expectation: str) -> None:
    raise ValueError(f"{key}: {expectation}")


def _is_number(value: Any) -> bool:
    return isinstance(value, Real) and not isinstance(value, bool) and np.isfinite(value)


def _coerce(key: str, current: Any, value: Any) -> Any:
    """`value` in the type and shape of the attribute's `current` value, or a `ValueError`."""
    if isinstance(current, np.ndarray):
        size = current.size
        if isinstance(value, str | bytes) or not hasattr(value, "__len__"):
            _fail(key, f"expected {size} numbers, got {value!r}")
        if len(value) != size:
            _fail(key, f"expected {size} numbers, got {len(value)}")
        if not all(_is_number(v) for v in value):
            _fail(key, f"expected {size} finite numbers, got {list(value)!r}")
        return np.asarray(value, dtype=current.dtype).reshape(current.shape)
    if isinstance(current, bool) or not isinstance(current, int | float):
        _fail(key, f"expected a numeric attribute; {type(current).__name__} is not overridable")
    if isinstance(current, int):
        if isinstance(value, bool) or not isinstance(value, Integral):
            _fail(key, f"expected an integer, got {value!r}")
        return int(value)
    if not _is_number(value):
        _fail(key, f"expected a finite number, got {value!r}")
    return float(value)


def _apply_option(spec: mujoco.MjSpec, name: str, value: Any, key: str) -> None:
    settable = [a for a in dir(spec.option) if not a.startswith("_") and a not in _OPTION_BITFIELDS]
    if name not in settable:
        _fail(key, f"unknown option; expected one of {', '.join(sorted(settable))}")
    if name in OPTION_KEYWORDS:
        keywords = OPTION_KEYWORDS[name]
        if value not in keywords:
            _fail(key, f"expected one of {', '.join(keywords)}, got {value!r}")
        setattr(spec.option, name, keywords.index(value))
        return
    coerced = _given(key, getattr(spec.option, name), value)
    if name in POSITIVE_OPTIONS and not coerced > 0:
        _fail(key, f"expected a positive number, got {value!r}")
    setattr(spec.option, name, coerced)


def factor_of(value: Any, key: str) -> float | None:
    """The factor an edit gives (`{factor: 0.7}` or `"x 0.7"`: the value as loaded times 0.7),
    or None for a value given outright; a `ValueError` for a malformed or non-positive one."""
    if isinstance(value, Mapping):
        if set(value) != {"factor"}:
            _fail(key, f"expected a value, or {{factor: <number>}}; got {dict(value)!r}")
        factor = value["factor"]
    elif isinstance(value, str) and value.strip()[:1] in ("x", "×"):
        try:
            factor = float(value.strip()[1:])
        except ValueError:
            _fail(key, f"expected 'x <number>' (a factor), got {value!r}")
    else:
        return None
    if not _is_number(factor) or factor <= 0:
        _fail(key, f"expected a positive factor, got {factor!r}")
    return float(factor)


def _apply_element(element: Any, name: str, value: Any, key: str) -> None:
    public = [a for a in dir(element) if not a.startswith("_")]
    if name in _NOT_SETTABLE or name not in public:
        _fail(key, "unknown or not overridable attribute")
    setattr(element, name, _given(key, getattr(element, name), value))


def _given(key: str, current: Any, value: Any) -> Any:
    """`value` as `_coerce` makes it, a factor (`factor_of`) times `current` first."""
    factor = factor_of(value, key)
    if factor is not None:
        if isinstance(current, bool) or not isinstance(current, float | np.ndarray):
            _fail(key, f"expected a numeric attribute of real numbers to scale, got {current!r}")
        value = (np.asarray(current, dtype=float) * factor).tolist()
    return _coerce(key, current, value)


# An actuator's MJCF attributes that MjSpec holds inside its parameter arrays, by what the
# actuator is (MuJoCo's XML reference, "actuator"; `MjsActuator.set_to_*` write the same): each
# attribute's numbers, each number the (array, index, sign) places it is written to. A
# position servo's `kp` is gainprm[0] and -biasprm[1]; a muscle's `force` is gainprm[2] and
# biasprm[2] (its force-length-velocity curve reads both), its `timeconst` two numbers.
_Places = tuple[tuple[str, int, float], ...]
_MUSCLE_PRM = ("force", "scale", "lmin", "lmax", "vmax", "fpmax", "fvmax")  # gainprm[2:9]
IN_ARRAYS: dict[str, dict[str, tuple[_Places, ...]]] = {
    "position": {
        "kp": ((("gainprm", 0, 1.0), ("biasprm", 1, -1.0)),),
        "kv": ((("biasprm", 2, -1.0),),),
    },
    "velocity": {"kv": ((("gainprm", 0, 1.0), ("biasprm", 2, -1.0)),)},
    "damper": {"kv": ((("gainprm", 2, -1.0),),)},
    "muscle": {
        **{
            name: ((("gainprm", 2 + i, 1.0), ("biasprm", 2 + i, 1.0)),)
            for i, name in enumerate(_MUSCLE_PRM)
        },
        "timeconst": ((("dynprm", 0, 1.0),), (("dynprm", 1, 1.0),)),
        "tausmooth": ((("dynprm", 2, 1.0),),),
    },
    "filtered": {"timeconst": ((("dynprm", 0, 1.0),),)},
}
ACTUATOR_ATTRIBUTES = frozenset(a for kind in IN_ARRAYS.values() for a in kind)


def actuator_kind(actuator: Any) -> str:
    """What an actuator is, as its MJCF element made it: muscle, position (gain kp, bias -kp
    on the length), velocity (gain kv, bias -kv on the velocity), damper (gain -kv times the
    velocity), filtered (activation through a filter: a `timeconst`), or general."""
    gain, bias = actuator.gainprm, actuator.biasprm
    if actuator.gaintype == mujoco.mjtGain.mjGAIN_MUSCLE:
        return "muscle"
    if actuator.gaintype == mujoco.mjtGain.mjGAIN_AFFINE and gain[0] == gain[1] == 0 > gain[2]:
        return "damper"
    if (
        actuator.gaintype == mujoco.mjtGain.mjGAIN_FIXED
        and gain[0] > 0
        and (actuator.biastype == mujoco.mjtBias.mjBIAS_AFFINE)
    ):
        if bias[1] == -gain[0]:
            return "position"
        if bias[1] == 0 and bias[2] == -gain[0]:
            return "velocity"
    if actuator.dyntype in (mujoco.mjtDyn.mjDYN_FILTER, mujoco.mjtDyn.mjDYN_FILTEREXACT):
        return "filtered"
    return "general"


def _apply_actuator_attribute(actuator: Any, name: str, value: Any, key: str) -> None:
    """Set an actuator's MJCF attribute (`kp`, a muscle's `force`) in the arrays that hold it,
    leaving their other numbers: `force: {factor: 0.7}` scales a muscle's peak force alone."""
    kind = actuator_kind(actuator)
    own = IN_ARRAYS.get(kind, {})
    if (
        kind != "muscle"
        and name == "timeconst"
        and actuator.dyntype
        in (
            mujoco.mjtDyn.mjDYN_FILTER,
            mujoco.mjtDyn.mjDYN_FILTEREXACT,
        )
    ):
        own = IN_ARRAYS["filtered"]
    if name not in own:
        _fail(
            key,
            f"this is a {kind} actuator, which has no {name!r}; expected kp or kv on a position "
            "servo, kv on a velocity servo or a damper, force, scale, lmin, lmax, vmax, fpmax, "
            "fvmax, timeconst or tausmooth on a muscle, timeconst with a filter's activation, "
            "or a field MjSpec holds (gear, forcerange, gainprm, ...)",
        )
    numbers = own[name]
    current = np.array([sign * getattr(actuator, a)[i] for (a, i, sign), *_ in numbers])
    factor = factor_of(value, key)
    if factor is not None and kind == "muscle" and name == "force" and current[0] < 0:
        _fail(
            key,
            "this muscle's force is MuJoCo's own (scale / acc0: force is negative in the "
            "model), so a factor of it has no base; expected `scale` by the factor, which "
            "scales that force alike, or a force in newtons",
        )
    if factor is not None:
        new = current * factor
    elif len(numbers) == 1:
        new = np.array([_coerce(key, 0.0, value)])
    else:
        new = _coerce(key, current, value)
    for places, number in zip(numbers, new, strict=True):
        for array, i, sign in places:
            values = np.array(getattr(actuator, array))
            values[i] = sign * number
            setattr(actuator, array, values)


def _class_parents(spec: mujoco.MjSpec) -> dict[str, str | None]:
    """Each default class's parent class (None for `main`): MjSpec does not expose the tree,
    its own MJCF does."""
    parents: dict[str, str | None] = {}

    def walk(node: ElementTree.Element, parent: str | None) -> None:
        name = node.get("class", "main")
        parents[name] = parent
        for child in node.findall("default"):
            walk(child, name)

    top = ElementTree.fromstring(spec.to_xml()).find("default")
    if top is not None:
        walk(top, None)
    return parents


def _same(a: Any, b: Any) -> bool:
    return bool(np.array_equal(a, b)) if isinstance(a, np.ndarray) else a == b


def _apply_default(spec: mujoco.MjSpec, name: str, kinds: Any, where: str) -> None:
    """Edit the class `name` as an edit of its `<default>` in the file would (module docstring)."""
    parents = _class_parents(spec)
    if spec.find_default(name) is None or name not in parents:
        _fail(
            where,
            f"the model has no default class of that name; expected one of {', '.join(parents)}",
        )
    if not isinstance(kinds, Mapping) or not kinds:
        _fail(where, f"expected a non-empty mapping of {', '.join(DEFAULT_ELEMENTS)}")
    for kind, attributes in kinds.items():
        if kind not in DEFAULT_ELEMENTS:
            _fail(f"{where}.{kind}", f"expected one of {', '.join(DEFAULT_ELEMENTS)}")
        if not isinstance(attributes, Mapping) or not attributes:
            _fail(f"{where}.{kind}", "expected a non-empty mapping of attributes")
        for attribute, value in attributes.items():
            key = f"{where}.{kind}.{attribute}"
            values = getattr(spec.find_default(name), kind)
            public = [a for a in dir(values) if not a.startswith("_")]
            if attribute in _NOT_SETTABLE or attribute not in public:
                _fail(key, "unknown or not overridable attribute")
            old = np.copy(getattr(values, attribute))
            new = _given(key, getattr(values, attribute), value)
            # the class, and each class below it that still inherits the value
            classes, frontier = {name}, [name]
            while frontier:
                parent = frontier.pop()
                for child, of in parents.items():
                    inherited = getattr(getattr(spec.find_default(child), kind), attribute)
                    if of == parent and _same(inherited, old):
                        classes.add(child)
                        frontier.append(child)
            for c in classes:
                setattr(getattr(spec.find_default(c), kind), attribute, new)
            for element in getattr(spec, DEFAULT_ELEMENTS[kind]):
                if element.classname.name in classes and _same(getattr(element, attribute), old):
                    setattr(element, attribute, new)


def _spec_element(
    spec: mujoco.MjSpec, kind: str, ref: str, key: str, compiled: list[mujoco.MjModel]
) -> Any:
    """The spec's element that `ref` names: a name, or an address (`#<index>`, `on:<name>`:
    `mjtrial.task.address`) resolved on the compiled spec, whose element lists are in the
    compiled model's order (tests/test_address.py checks it for every kind here)."""
    if not ref.startswith(("#", "on:")):
        element = getattr(spec, kind)(ref)  # spec.geom(name), spec.joint(name), ...
        if element is None:
            _fail(
                key,
                f"the model has no {kind} of that name; an unnamed one: '#<index>' or 'on:<name>'",
            )
        return element
    if not compiled:
        compiled.append(_compiled(spec, source=key)[0])
    try:
        index = address.resolve(compiled[0], kind, ref)
    except address.AddressError as err:
        _fail(key, str(err))
    return getattr(spec, SPEC_ELEMENTS[kind])[index]


def _index(spec: mujoco.MjSpec, kind: str, element: Any) -> int:
    """The element's place in the spec's list of its kind: the compiled model's index."""
    return next(i for i, e in enumerate(getattr(spec, SPEC_ELEMENTS[kind])) if e == element)


def resolved_values(model_file: Path | str, edits: Mapping[str, Any]) -> dict[str, str]:
    """Each value `edits` set (`edited_values`), keyed by the element it reaches: an element's
    value as `<kind>.#<index>.<attribute>` whatever name or address gave it (`floor`, `#0`,
    `on:...`), an option's or a class's as `edited_values` gives it; each mapped to the key
    the edits gave. Edits `apply_overrides` accepted."""
    spec = load_spec(model_file)
    compiled: list[mujoco.MjModel] = []
    found: dict[str, str] = {}
    for kind, entries in edits.items():
        if kind in ("option", "default"):
            found |= {k: k for k in edited_values({kind: entries})}
            continue
        for ref, attributes in entries.items():
            element = _spec_element(spec, kind, ref, f"{kind}.{ref}", compiled)
            index = _index(spec, kind, element)
            found |= {f"{kind}.#{index}.{a}": f"{kind}.{ref}.{a}" for a in attributes}
    return found


def apply_overrides(
    spec: mujoco.MjSpec, overrides: Mapping[str, Any], *, key_prefix: str = "overrides"
) -> None:
    """Set every override on `spec` in place; a bad one raises a one-line `ValueError`.

    The message names the key (`<key_prefix>.<kind>.<element>.<attribute>`) and what was
    expected: an unknown kind, option, element or attribute, a wrongly shaped or typed value,
    an unknown keyword (integrator, cone, solver, jacobian), a non-positive timestep or impratio.
    """
    if not isinstance(overrides, Mapping):
        _fail(key_prefix, f"expected a mapping of {', '.join(OVERRIDE_KINDS)}")
    compiled: list[mujoco.MjModel] = []  # the spec compiled once, if an address needs it
    edited: dict[tuple[str, int], str] = {}  # (kind, element's index) -> the name it was given
    for kind, entries in overrides.items():
        where = f"{key_prefix}.{kind}"
        if kind not in OVERRIDE_KINDS:
            _fail(where, f"unknown override kind; expected one of {', '.join(OVERRIDE_KINDS)}")
        if not isinstance(entries, Mapping) or not entries:
            _fail(where, "expected a non-empty mapping")
        if kind == "option":
            for name, value in entries.items():
                _apply_option(spec, name, value, f"{where}.{name}")
            continue
        if kind == "default":
            for name, kinds in entries.items():
                _apply_default(spec, name, kinds, f"{where}.{name}")
            continue
        for element_name, attributes in entries.items():
            element = _spec_element(spec, kind, element_name, f"{where}.{element_name}", compiled)
            first = edited.setdefault((kind, _index(spec, kind, element)), element_name)
            if first != element_name:
                _fail(
                    f"{where}.{element_name}",
                    f"the same {kind} as {where}.{first}; expected each element once, under one "
                    "name (else the last edit would win)",
                )
            if not isinstance(attributes, Mapping) or not attributes:
                _fail(f"{where}.{element_name}", "expected a non-empty mapping of attributes")
            for name, value in attributes.items():
                key = f"{where}.{element_name}.{name}"
                if kind == "actuator" and name in ACTUATOR_ATTRIBUTES:
                    _apply_actuator_attribute(element, name, value, key)
                else:
                    _apply_element(element, name, value, key)


def _compiled(spec: mujoco.MjSpec, *, source: str) -> tuple[mujoco.MjModel, str]:
    # Compiled from the edited spec itself, never through `to_xml()`: the XML round trip is not
    # exact (a quaternion from `fromto` came back 6e-17 apart) and its text depends on what the
    # process did before (`physics.compiled_sha256`).
    try:
        model = spec.compile()
    except ValueError as err:
        text = str(err).strip().replace(str(Path.cwd().resolve()) + "/", "")
        first = text.splitlines()[0] if text else "compile error"
        raise ModelError(f"{source}: MuJoCo could not compile the model: {first}") from None
    return model, compiled_sha256(model)


def check_overrides(
    overrides: Mapping[str, Any], *, model_file: Path | str, key_prefix: str
) -> None:
    """Raise a one-line `ValueError` naming the key if `overrides` cannot apply to the model.

    Applies them to a fresh spec of `model_file` (nothing is compiled), so every element name
    is checked against the model itself.
    """
    apply_overrides(load_spec(model_file), overrides, key_prefix=key_prefix)


def variant_model(
    model_file: Path | str,
    overrides: Mapping[str, Any],
    *,
    key_prefix: str = "overrides",
    then: Sequence[tuple[Mapping[str, Any], str]] = (),
) -> tuple[mujoco.MjModel, str]:
    """The model of `model_file` with `overrides` applied, and its sha256.

    `then` are further edits, each with its key prefix, applied after `overrides` in order: a
    variant's, then a condition's own (`conditions.<name>.model`). Returns the compiled model
    and its hex sha256 (`physics.compiled_sha256`); with no edits this is the nominal model,
    identical to `physics.load_model(model_file)`, and its hash (`nominal_model_hash`).
    """
    spec = load_spec(model_file)
    apply_overrides(spec, overrides, key_prefix=key_prefix)
    for edits, prefix in then:
        apply_overrides(spec, edits, key_prefix=prefix)
    return _compiled(spec, source=f"{model_file} ({key_prefix})")


def nominal_model_hash(model_file: Path | str) -> str:
    """The sha256 of the unedited compiled model, hashed as the variants' are."""
    return variant_model(model_file, {})[1]


def edited_values(edits: Mapping[str, Any]) -> list[str]:
    """Each value that edits set, by its key below their prefix: `option.timestep`,
    `geom.floor.friction`, `default.main.joint.damping` (edits `apply_overrides` accepted)."""
    keys = []
    for kind, entries in edits.items():
        if kind == "option":
            keys += [f"option.{name}" for name in entries]
        elif kind == "default":
            keys += [
                f"default.{name}.{of}.{attribute}"
                for name, kinds in entries.items()
                for of, attributes in kinds.items()
                for attribute in attributes
            ]
        else:
            keys += [f"{kind}.{e}.{a}" for e, attributes in entries.items() for a in attributes]
    return keys


def describe_edits(edits: Mapping[str, Any]) -> str:
    """Edits in a line of the report: `joint hinge frictionloss 0.2; option timestep 0.001`."""
    parts = []
    for kind, entries in edits.items():
        if kind == "option":
            parts += [f"option {name} {_shown(v)}" for name, v in entries.items()]
            continue
        if kind == "default":  # `default main joint damping 0.03 0 0`
            parts += [
                f"default {name} {of} {attribute} {_shown(v)}"
                for name, kinds in entries.items()
                for of, attributes in kinds.items()
                for attribute, v in attributes.items()
            ]
            continue
        for element, attributes in entries.items():
            parts += [f"{kind} {element} {name} {_shown(v)}" for name, v in attributes.items()]
    return "; ".join(parts)


def _shown(value: Any) -> str:
    if isinstance(value, Mapping):  # {factor: 0.7}
        return f"x {value['factor']:g}"
    if isinstance(value, str):
        return value
    if isinstance(value, Sequence):
        return " ".join(f"{v:g}" for v in value)
    return f"{value:g}"
