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
    excluded = model.exclude_signature
    filter_parent = not model.opt.disableflags & mujoco.mjtDisableBit.mjDSBL_FILTERPARENT
    weld = model.body_weldid
    weld_parent = weld[model.body_parentid[weld]]
    contype, conaffinity, body = model.geom_contype, model.geom_conaffinity, model.geom_bodyid
    for g1 in range(model.ngeom - 1):  # each geom against those after it, at once
        g2 = np.arange(g1 + 1, model.ngeom)
        b1, b2 = body[g1], body[g2]
        w1, w2 = weld[b1], weld[b2]
        keep = ((contype[g1] & conaffinity[g2]) | (contype[g2] & conaffinity[g1])) != 0
        keep &= (w1 != w2) & ((model.body_dofnum[w1] > 0) | (model.body_dofnum[w2] > 0))
        if filter_parent:
            keep &= ~((w1 != 0) & (w2 != 0) & ((w1 == weld_parent[b2]) | (w2 == weld_parent[b1])))
        keep &= ~np.isin((np.minimum(b1, b2) << 16) + np.maximum(b1, b2), excluded)
        pairs.update((g1, int(g)) for g in g2[keep])
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


def _name(model: mujoco.MjModel, g: int) -> str:
    """A geom as the report names it: `block`, or `geom 3 of body left_jaw`."""
    from mjtrial.task.address import describe  # here: `physics` imports this module early

    return f"`{describe(model, mujoco.mjtObj.mjOBJ_GEOM, g)}`"


def _table(model: mujoco.MjModel, pairs: list[tuple[int, int]]) -> dict[str, np.ndarray]:
    """`mj_contactParam` for many geom pairs at once, then each `<pair>`'s own values and the
    option's override: arrays over the pairs, in their order (the keys of `PairContact`, and
    `pair`, -1 where none; `mix`, solmix's weight on the first geom; `winner`, the geom whose
    higher priority gave its values, -1 where none)."""
    g1 = np.array([p[0] for p in pairs], dtype=int)
    g2 = np.array([p[1] for p in pairs], dtype=int)
    take = lambda field: (getattr(model, field)[g1], getattr(model, field)[g2])  # noqa: E731
    s1, s2 = take("geom_solmix")
    both = (s1 >= _MINVAL) & (s2 >= _MINVAL)
    mix = np.where(
        both,
        s1 / np.where(both, s1 + s2, 1.0),
        np.where((s1 < _MINVAL) & (s2 < _MINVAL), 0.5, np.where(s1 < _MINVAL, 0.0, 1.0)),
    )[:, None]
    r1, r2 = take("geom_solref")
    standard = ((r1[:, 0] > 0) & (r2[:, 0] > 0))[:, None]
    i1, i2 = take("geom_solimp")
    out = {
        "condim": np.maximum(*take("geom_condim")),
        "friction": np.maximum(*take("geom_friction")),
        # a direct reference (stiffness, damping as negative numbers): the smaller
        "solref": np.where(standard, mix * r1 + (1 - mix) * r2, np.minimum(r1, r2)),
        "solimp": mix * i1 + (1 - mix) * i2,
        "adhesion": np.add(*take("geom_adhesion")),
    }
    p1, p2 = take("geom_priority")
    winner = np.where(p1 > p2, g1, np.where(p1 < p2, g2, -1))
    higher = winner >= 0
    for key, field in (
        ("condim", "geom_condim"),
        ("friction", "geom_friction"),
        ("solref", "geom_solref"),
        ("solimp", "geom_solimp"),
        ("adhesion", "geom_adhesion"),
    ):
        out[key][higher] = getattr(model, field)[winner[higher]]
    out["friction"] = out["friction"][:, [0, 0, 1, 2, 2]]
    out |= {
        "solreffriction": np.zeros((len(pairs), 2)),
        "margin": np.add(*take("geom_margin")),
        "gap": np.add(*take("geom_gap")),
        "mix": mix[:, 0],
        "winner": winner,
        "pair": np.full(len(pairs), -1),
    }
    row = {p: i for i, p in enumerate(pairs)}
    for i, (a, b) in enumerate(zip(model.pair_geom1, model.pair_geom2, strict=True)):
        k = row.get((min(a, b), max(a, b)))
        if k is None:
            continue  # (two `<pair>`s of the same geoms both collide: the later one is said)
        out["pair"][k] = i
        for key, field in (
            ("condim", "pair_dim"),
            ("friction", "pair_friction"),
            ("solref", "pair_solref"),
            ("solimp", "pair_solimp"),
            ("solreffriction", "pair_solreffriction"),
            ("adhesion", "pair_adhesion"),
            ("margin", "pair_margin"),
            ("gap", "pair_gap"),
        ):
            out[key][k] = getattr(model, field)[i]
    if model.opt.enableflags & mujoco.mjtEnableBit.mjENBL_OVERRIDE:
        out["margin"][:] = model.opt.o_margin
        out["solref"][:] = out["solreffriction"][:] = model.opt.o_solref
        out["solimp"][:] = model.opt.o_solimp
        out["friction"][:] = model.opt.o_friction
    out["friction"] = np.maximum(out["friction"], _MINMU)
    return out


def pair_contacts(model: mujoco.MjModel) -> list[PairContact]:
    """Every pair of geoms that can touch (`collision_pairs`) with its contacts' parameters; a
    `<pair>` replaces the mixed values of its two geoms."""
    pairs = collision_pairs(model)
    t = _table(model, pairs)
    override = model.opt.enableflags & mujoco.mjtEnableBit.mjENBL_OVERRIDE
    contacts = []
    for i, (g1, g2) in enumerate(pairs):
        if override:
            rule = "`<option>` override"
        elif t["pair"][i] >= 0:
            rule = f"`<pair>` {t['pair'][i]}"
        elif t["winner"][i] >= 0:
            rule = f"{_name(model, int(t['winner'][i]))}'s (higher priority)"
        else:
            mix = t["mix"][i]
            rule = "mixed" + (
                "" if mix == 0.5 else f" (solmix weight {mix:.3g} on {_name(model, g1)})"
            )
        contacts.append(
            PairContact(
                geoms=(g1, g2),
                pair=int(t["pair"][i]) if t["pair"][i] >= 0 else None,
                condim=int(t["condim"][i]),
                friction=tuple(float(v) for v in t["friction"][i]),
                solref=tuple(float(v) for v in t["solref"][i]),
                solimp=tuple(float(v) for v in t["solimp"][i]),
                solreffriction=tuple(float(v) for v in t["solreffriction"][i]),
                adhesion=float(t["adhesion"][i]),
                margin=float(t["margin"][i]),
                gap=float(t["gap"][i]),
                rule=rule,
            )
        )
    return contacts


def contact_digest_values(model: mujoco.MjModel) -> np.ndarray:
    """The pairs and their mixed parameters as one float64 array, for the simulation's hash:
    what MuJoCo reads of `MIXED_GEOM_FIELDS` (never read otherwise), so a geom edit no pair
    sees hashes the same. Each row: the two geom ids, condim, friction (5), solref (2),
    solimp (5), adhesion."""
    pairs = collision_pairs(model)
    if not pairs:
        return np.zeros((0, 16))
    t = _table(model, pairs)
    columns = [np.array(pairs, dtype=float).reshape(-1, 2), t["condim"][:, None]]
    columns += [t["friction"], t["solref"], t["solimp"], t["adhesion"][:, None]]
    return np.hstack([np.asarray(c, dtype=np.float64).reshape(len(pairs), -1) for c in columns])


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
