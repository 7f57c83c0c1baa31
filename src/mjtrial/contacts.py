"""Contacts as MuJoCo makes them: which geom pairs can touch, and the parameters each pair's
contacts take, mixed from its two geoms the way MuJoCo mixes them (`mj_contactParam` in
`engine_collision_driver.c`), or a `<pair>`'s own.

MuJoCo's rule (MuJoCo 3.14, measured against its own contacts: `tests/test_contacts.py`) for
two geoms of the same `priority`: friction is the larger of the two per component, condim the
larger; solref and solimp are mixed by the `solmix` weights (mix = solmix1 / (solmix1 +
solmix2); 0.5 when both are below mjMINVAL, all of the one whose solmix is not when only one
is), except a direct (non-positive) solref, where the smaller of each number is taken; adhesion
is the sum. Different priorities: the higher one's condim, friction, solref, solimp and
adhesion. Whatever the priorities, the margin (each geom's inflation) and the gap (each geom's
extra detection distance) are the sums of the two. A `<pair>` uses its own values, which
replace the geoms' for that pair. With `<option><flag override="enable"/>` the option's
`o_margin`, `o_solref`, `o_solimp` and `o_friction` replace them.

A geom's own friction is therefore not what its contacts use: a block at 0.5 held by jaws at 2.0
slides at 2.0 either way. The report says each pair's values (`mjtrial.report.model`), an edit
is described by what it changes in them (`describe_contact_changes`), and the simulation's hash
(`physics.simulated_sha256`) reads the pairs' values instead of the geoms', so an edit that no
pair sees changes nothing and is refused.
"""

from __future__ import annotations

from dataclasses import dataclass
from itertools import combinations

import mujoco
import numpy as np

_MINVAL = 1e-15  # mjMINVAL
_MINMU = 1e-5  # mjMINMU: MuJoCo's floor on each friction coefficient
# The geom fields MuJoCo reads only to mix a pair's contact parameters (`mj_contactParam`).
MIXED_GEOM_FIELDS = (
    "geom_condim",
    "geom_friction",
    "geom_priority",
    "geom_solimp",
    "geom_solmix",
    "geom_solref",
)


def contacts_enabled(model: mujoco.MjModel) -> bool:
    """False when `<option><flag contact="disable"/>` (or constraint) turns every contact off."""
    off = mujoco.mjtDisableBit.mjDSBL_CONTACT | mujoco.mjtDisableBit.mjDSBL_CONSTRAINT
    return not model.opt.disableflags & off


def collision_pairs(model: mujoco.MjModel) -> list[tuple[int, int]]:
    """The geom pairs (ids, ascending) that MuJoCo's collision filter lets through: the
    explicit `<pair>`s, and the pairs whose contype and conaffinity match (bitwise), on different
    weld bodies (bodies joined without a joint move as one) of which at least one has a degree of
    freedom (two dof-less weld bodies, the world's and mocap bodies, are never tested), not parent
    and child weld bodies unless filterparent is disabled (the world is no one's parent here),
    not `<exclude>`d. Their distance is another matter: two geoms that can never come near each
    other are listed."""
    if not contacts_enabled(model):
        return []
    pairs = {tuple(sorted(p)) for p in zip(model.pair_geom1, model.pair_geom2, strict=True)}
    excluded = set(model.exclude_signature.tolist())
    filter_parent = not model.opt.disableflags & mujoco.mjtDisableBit.mjDSBL_FILTERPARENT
    weld = model.body_weldid
    weld_parent = weld[model.body_parentid[weld]]
    for g1, g2 in combinations(range(model.ngeom), 2):
        if not (
            model.geom_contype[g1] & model.geom_conaffinity[g2]
            or model.geom_contype[g2] & model.geom_conaffinity[g1]
        ):
            continue
        b1, b2 = model.geom_bodyid[g1], model.geom_bodyid[g2]
        w1, w2 = weld[b1], weld[b2]
        if w1 == w2 or not (model.body_dofnum[w1] or model.body_dofnum[w2]):
            continue
        if filter_parent and w1 and w2 and (w1 == weld_parent[b2] or w2 == weld_parent[b1]):
            continue
        if ((min(b1, b2) << 16) + max(b1, b2)) in excluded:
            continue
        pairs.add((g1, g2))
    return sorted((int(a), int(b)) for a, b in pairs)


@dataclass(frozen=True)
class PairContact:
    """The parameters of every contact between two geoms, as MuJoCo sets them on `mjContact`.

    Attributes:
      geoms: the two geom ids, ascending.
      pair: the index of the `<pair>` that sets them, or None (mixed from the geoms).
      condim: 1, 3, 4 or 6.
      friction: (5,) sliding, sliding, torsional, rolling, rolling (`mjContact.friction`).
      solref: (2,); solimp: (5,); solreffriction: (2,), a `<pair>`'s (zeros: as solref);
        adhesion: newtons; margin, gap: metres (a contact is
        detected within margin + gap, and acts within margin).
      rule: where they come from, in words ("mixed", "`jaw`'s (higher priority)",
        "`<pair>` 0").
    """

    geoms: tuple[int, int]
    pair: int | None
    condim: int
    friction: tuple[float, ...]
    solref: tuple[float, ...]
    solimp: tuple[float, ...]
    solreffriction: tuple[float, ...]
    adhesion: float
    margin: float
    gap: float
    rule: str

    def values(self) -> tuple:
        """What a contact of the pair reads: equal values, equal contacts."""
        return (
            *(self.condim, self.friction, self.solref, self.solimp, self.solreffriction),
            *(self.adhesion, self.margin, self.gap),
        )


def _mix(model: mujoco.MjModel, g1: int, g2: int) -> tuple:
    """`mj_contactParam` for two geoms: condim, friction (3,), solref, solimp, adhesion, rule."""
    p1, p2 = model.geom_priority[g1], model.geom_priority[g2]
    if p1 != p2:
        g = g1 if p1 > p2 else g2
        rule = f"{_name(model, g)}'s (higher priority)"
        return (
            int(model.geom_condim[g]),
            model.geom_friction[g].copy(),
            model.geom_solref[g].copy(),
            model.geom_solimp[g].copy(),
            float(model.geom_adhesion[g]),
            rule,
        )
    s1, s2 = model.geom_solmix[g1], model.geom_solmix[g2]
    if s1 >= _MINVAL and s2 >= _MINVAL:
        mix = s1 / (s1 + s2)
    elif s1 < _MINVAL and s2 < _MINVAL:
        mix = 0.5
    else:
        mix = 0.0 if s1 < _MINVAL else 1.0
    r1, r2 = model.geom_solref[g1], model.geom_solref[g2]
    if r1[0] > 0 and r2[0] > 0:
        solref = mix * r1 + (1 - mix) * r2
    else:  # a direct reference (stiffness, damping as negative numbers): the smaller
        solref = np.minimum(r1, r2)
    solimp = mix * model.geom_solimp[g1] + (1 - mix) * model.geom_solimp[g2]
    friction = np.maximum(model.geom_friction[g1], model.geom_friction[g2])
    condim = int(max(model.geom_condim[g1], model.geom_condim[g2]))
    rule = "mixed" + ("" if mix == 0.5 else f" (solmix weight {mix:.3g} on {_name(model, g1)})")
    adhesion = float(model.geom_adhesion[g1] + model.geom_adhesion[g2])
    return condim, friction, solref, solimp, adhesion, rule


def _name(model: mujoco.MjModel, g: int) -> str:
    """A geom as the report names it: `block`, or `geom 3 of body left_jaw`."""
    from mjtrial.task.address import describe  # here: `physics` imports this module early

    return f"`{describe(model, mujoco.mjtObj.mjOBJ_GEOM, g)}`"


def pair_contact(
    model: mujoco.MjModel, g1: int, g2: int, *, pair: int | None = None
) -> PairContact:
    """The parameters of the contacts between geoms `g1` and `g2` (`pair`: the `<pair>` that
    names them, which sets its own)."""
    if pair is not None:
        condim = int(model.pair_dim[pair])
        friction = model.pair_friction[pair].copy()
        solref = model.pair_solref[pair].copy()
        solimp = model.pair_solimp[pair].copy()
        solreffriction = model.pair_solreffriction[pair].copy()
        adhesion = float(model.pair_adhesion[pair])
        margin, gap = float(model.pair_margin[pair]), float(model.pair_gap[pair])
        rule = f"`<pair>` {pair}"
    else:
        condim, fri, solref, solimp, adhesion, rule = _mix(model, g1, g2)
        friction = fri[[0, 0, 1, 2, 2]]
        solreffriction = np.zeros(2)
        margin = float(model.geom_margin[g1] + model.geom_margin[g2])
        gap = float(model.geom_gap[g1] + model.geom_gap[g2])
    if model.opt.enableflags & mujoco.mjtEnableBit.mjENBL_OVERRIDE:
        margin = float(model.opt.o_margin)
        solref, solimp = model.opt.o_solref.copy(), model.opt.o_solimp.copy()
        solreffriction = model.opt.o_solref.copy()
        friction = model.opt.o_friction.copy()
        rule = "`<option>` override"
    friction = np.maximum(friction, _MINMU)
    return PairContact(
        geoms=(min(g1, g2), max(g1, g2)),
        pair=pair,
        condim=condim,
        friction=tuple(float(v) for v in friction),
        solref=tuple(float(v) for v in solref),
        solimp=tuple(float(v) for v in solimp),
        solreffriction=tuple(float(v) for v in solreffriction),
        adhesion=adhesion,
        margin=margin,
        gap=gap,
        rule=rule,
    )


def pair_contacts(model: mujoco.MjModel) -> list[PairContact]:
    """Every pair of geoms that can touch (`collision_pairs`) with its contacts' parameters; a
    `<pair>` replaces the mixed values of its two geoms (the last one naming them wins)."""
    explicit = {
        tuple(sorted((int(a), int(b)))): i
        for i, (a, b) in enumerate(zip(model.pair_geom1, model.pair_geom2, strict=True))
    }
    return [
        pair_contact(model, g1, g2, pair=explicit.get((g1, g2)))
        for g1, g2 in collision_pairs(model)
    ]


def contact_digest_values(model: mujoco.MjModel) -> np.ndarray:
    """The pairs and their mixed parameters as one float64 array, for the simulation's hash:
    what MuJoCo reads of `MIXED_GEOM_FIELDS` (never read otherwise), so a geom edit no pair
    sees hashes the same. Each row: the two geom ids, condim, friction (5), solref (2),
    solimp (5)."""
    rows = [(*c.geoms, c.condim, *c.friction, *c.solref, *c.solimp) for c in pair_contacts(model)]
    return np.asarray(rows, dtype=np.float64).reshape(len(rows), 15)


def describe_contact_changes(
    before: mujoco.MjModel, after: mujoco.MjModel, *, max_pairs: int = 6
) -> list[str]:
    """What an edit of geoms does to their contacts, in a line per edited geom: "`block`
    friction 1 0.005 0.0001 -> 0.5 0.005 0.0001; its contacts with `left_jaw`, `right_jaw`
    keep friction 2 0.005 0.0001; its contacts with `floor` (friction 1 ... -> 0.8 ...)
    change". Only geoms whose contact fields changed are said; the models must have the same
    geoms."""
    old = {c.geoms: c for c in pair_contacts(before)}
    new = {c.geoms: c for c in pair_contacts(after)}
    lines = []
    for g in range(after.ngeom):
        fields = [
            field
            for field in _CONTACT_FIELDS
            if not np.array_equal(getattr(before, field)[g], getattr(after, field)[g])
        ]
        if not fields:
            continue
        shown = sorted({s for f in fields for s in _CONTACT_FIELDS[f]}, key=_PAIR_FIELDS.index)
        touching = [k for k in sorted(set(old) | set(new)) if g in k]
        kept: dict[str, list[str]] = {}
        changed = []
        for key in touching:
            other = _name(after, key[0] if key[1] == g else key[1])
            a, b = old.get(key), new.get(key)
            if a is not None and b is not None and a.values() == b.values():
                values = ", ".join(f"{f} {_shown(_pair_value(b, f))}" for f in shown)
                kept.setdefault(values, []).append(other)
            else:
                changed.append(f"{other} ({_pair_change(a, b)})")
        edited = ", ".join(
            f"{f.removeprefix('geom_')} {_shown(getattr(before, f)[g])} -> "
            f"{_shown(getattr(after, f)[g])}"
            for f in fields
        )
        parts = [f"{_name(after, g)} {edited}"]
        if not touching:
            parts.append("it touches no geom (contype, conaffinity)")
        if changed:
            parts.append(f"its contacts with {_listed(changed, max_pairs)} change")
        parts += [
            f"its contacts with {_listed(others, max_pairs)} keep {values}"
            for values, others in kept.items()
        ]
        lines.append("; ".join(parts))
    return lines


# Each geom field an edit may change, with the fields of its pairs' contacts it can move.
_PAIR_FIELDS = ("condim", "friction", "solref", "solimp", "adhesion", "margin", "gap")
_CONTACT_FIELDS = {
    "geom_friction": ("friction",),
    "geom_condim": ("condim",),
    "geom_solref": ("solref",),
    "geom_solimp": ("solimp",),
    "geom_solmix": ("solref", "solimp"),
    "geom_priority": ("condim", "friction", "solref", "solimp", "adhesion"),
    "geom_adhesion": ("adhesion",),
    "geom_margin": ("margin",),
    "geom_gap": ("gap",),
}


def _pair_value(c: PairContact, field: str):
    return _three(c.friction) if field == "friction" else getattr(c, field)


def _pair_change(a: PairContact | None, b: PairContact | None) -> str:
    if a is None or b is None:
        return "can touch now" if a is None else "can no longer touch"
    parts = [
        f"{f} {_shown(_pair_value(a, f))} -> {_shown(_pair_value(b, f))}"
        for f in _PAIR_FIELDS
        if _pair_value(a, f) != _pair_value(b, f)
    ]
    return ", ".join(parts) or "solreffriction changes"


def _three(friction: tuple[float, ...]) -> tuple[float, ...]:
    """Sliding, torsional, rolling: the geom's three of a contact's five."""
    return friction[0], friction[2], friction[3]


def _listed(items: list[str], at_most: int) -> str:
    shown = ", ".join(items[:at_most])
    return shown + (f" and {len(items) - at_most} more" if len(items) > at_most else "")


def _shown(value) -> str:
    values = np.atleast_1d(np.asarray(value, dtype=float))
    return " ".join(f"{v:g}" for v in values)


def contact_lines(model: mujoco.MjModel, *, max_pairs: int = 24) -> list[str]:
    """The report's lines on contacts: the pairs that can collide, then what their contacts
    use, as MuJoCo mixes it (pairs with the same values share a row)."""
    if not contacts_enabled(model):
        return ["- Contacts: disabled in the model's `<option>`; no geom collides."]
    contacts = pair_contacts(model)
    if not contacts:
        return ["- Contacts: no two geoms of the model can collide (contype, conaffinity)."]
    first = _geoms(contacts, max_pairs)
    shown = ", ".join(f"{_name(model, a)}–{_name(model, b)}" for a, b in first)
    more = f", and {len(contacts) - max_pairs} more" if len(contacts) > max_pairs else ""
    rows: dict[tuple, list[PairContact]] = {}
    for c in contacts:
        rows.setdefault((c.values(), c.rule), []).append(c)
    lines = [
        f"- Contacts: {len(contacts)} geom pairs pass MuJoCo's collision filter (whether they "
        f"come near each other is not checked): {shown}{more}. What their contacts use, as "
        "MuJoCo mixes it from the two geoms (the larger friction and condim, solref and solimp "
        "weighted by solmix, margin and gap summed; the higher priority's values where "
        "priorities differ; a `<pair>`'s own), so a geom's own friction is not its contacts': "
        "pairs with the same values share a row.",
        "",
        "| pairs | condim | friction (sliding, torsional, rolling) | solref | solimp "
        "| margin, gap (m) | from |",
        "| --- | --- | --- | --- | --- | --- | --- |",
    ]
    for (_, rule), group in rows.items():
        c = group[0]
        named = [f"{_name(model, a)} & {_name(model, b)}" for a, b in _geoms(group, 6)]
        listed = ", ".join(named) + (f" and {len(group) - 6} more" if len(group) > 6 else "")
        adhesion = f", adhesion {c.adhesion:g} N" if c.adhesion else ""
        cell = lambda values: ", ".join(f"{v:g}" for v in values)  # noqa: E731
        lines.append(
            f"| {listed} | {c.condim} | {cell(_three(c.friction))} | {cell(c.solref)} "
            f"| {cell(c.solimp)}{adhesion} | {c.margin:g}, {c.gap:g} | {rule} |"
        )
    return lines


def _geoms(contacts: list[PairContact], at_most: int) -> list[tuple[int, int]]:
    return [c.geoms for c in contacts[:at_most]]
