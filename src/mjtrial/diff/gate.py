"""A diff as text, and as a regression gate: what `--fail-on any|changed|verdict` fails on."""

from __future__ import annotations

from collections import Counter
from collections.abc import Mapping
from typing import Any

from mjtrial.diff.flips import SHOWN_FLIPS
from mjtrial.diff.registration import registration_lines
from mjtrial.recording.divergence import describe_divergence

# A condition's result changed beyond noise when McNemar's exact test on the shared states
# gives a p below this.
DEFAULT_LEVEL = 0.05
FAIL_ON = ("any", "changed", "verdict")
_SHOWN = 5  # outputs named per kind; the rest counted


def _names(paths: list[str]) -> str:
    more = f" and {len(paths) - _SHOWN} more" if len(paths) > _SHOWN else ""
    return ", ".join(paths[:_SHOWN]) + more


def _pct(rate: Mapping[str, Any]) -> str:
    if not rate["n"]:
        return "no episodes"
    return f"{100 * rate['rate']:.1f}% ({rate['successes']}/{rate['n']})"


def _changed_conditions(diff: Mapping[str, Any]) -> list[str]:
    out = []
    for group, rec in diff["conditions"].items():
        paired = rec.get("paired") or {}
        p = paired.get("p_value")
        if p is not None and p < diff["level"]:
            out.append(
                f"{group}: success {_pct(paired['a'])} -> {_pct(paired['b'])} on "
                f"{paired['n']} shared states, McNemar exact p = {p:.3g} < {diff['level']:g}"
            )
    return out


# What a run holds that is not what it sealed (`found.not_as_sealed`), in words.
_NOT_AS_SEALED = (
    ("altered", "outputs no longer match their seal"),
    ("missing", "sealed outputs missing"),
    ("rows", "tables whose rows are not the ones their stamp records"),
)


def _not_as_sealed(outputs: Mapping[str, list[str]]) -> list[str]:
    return [
        f"{what} in {side}: {_names(outputs[f'{kind}_{side}'])}"
        for side in "ab"
        for kind, what in _NOT_AS_SEALED
        if outputs.get(f"{kind}_{side}")
    ]


def failures(diff: Mapping[str, Any], fail_on: str) -> list[str]:
    """One line per reason the gate `fail_on` (`FAIL_ON`) fails; none: it passes.

    Every gate fails on a run whose files are not what it sealed (an output edited or gone,
    a table whose rows are not its stamp's): what it found is not what is compared.
    `any`: also an output is in one run only, or its content differs beyond its stamp, or the
    registered designs differ (`diff.registration`); `changed`:
    a condition's success on the shared states differs beyond noise (McNemar's exact p below
    the diff's `level`); `verdict`: a verdict differs (the falsifier's, the experiment's or a
    variant's of the sensitivity study; a benchmark's comparison of two methods)."""
    if fail_on not in FAIL_ON:
        raise ValueError(f"fail_on: expected one of {list(FAIL_ON)}, got {fail_on!r}")
    outputs = diff.get("outputs") or {}
    broken = _not_as_sealed(outputs)
    if fail_on == "any":
        lines = broken + [
            f"{what}: {_names(outputs[key])}"
            for key, what in (
                ("differ", "outputs differ"),
                ("only_a", "outputs only in a"),
                ("only_b", "outputs only in b"),
            )
            if outputs[key]
        ]
        lines += [
            f"{g}: rolled out in {r['only']} only"
            for g, r in diff["conditions"].items()
            if "only" in r
        ]
        registered = diff.get("registration") or {}
        if registered.get("changed"):
            keys = [c["key"] for c in registered.get("changes", [])]
            lines.append(
                "registration: the registered design differs"
                + (f" ({', '.join(keys)})" if keys else " (registered in one run only)")
            )
        return lines
    if fail_on == "changed":
        return broken + _changed_conditions(diff)
    return broken + [
        f"{name}: verdict changed: {rec['a'] and rec['a']['verdict']} -> "
        f"{rec['b'] and rec['b']['verdict']}"
        for name, rec in diff["effects"].items()
        if rec["changed"]
    ]


def _value(value: Any) -> str:
    if value is None:
        return "(absent)"
    if isinstance(value, str) and len(value) == 64 and all(c in "0123456789abcdef" for c in value):
        return value[:12]  # a sha256
    if isinstance(value, list):
        return "[" + ", ".join(_value(v) for v in value) + "]"
    return str(value)


def _made_lines(made: Mapping[str, list[Mapping[str, Any]]]) -> list[str]:
    lines = []
    for section, rows in made.items():
        for row in rows:
            extra = f" (modules: {', '.join(row['modules'])})" if row.get("modules") else ""
            # the commit section's one key is the section itself: "commit: <a> -> <b>"
            key = section if row["key"] == section else f"{section}: {row['key']}"
            lines.append(f"  {key}: {_value(row['a'])} -> {_value(row['b'])}{extra}")
    return lines or ["  nothing differs (commit, code, config, model, versions, platform)"]


def _effect(e: Mapping[str, Any] | None) -> str:
    if e is None:
        return "(none)"
    if e["estimate"] is None:
        return str(e["verdict"])
    if e["low"] is None:
        return f"{e['estimate']:+.3f} {e['verdict']}"
    return f"{e['estimate']:+.3f} [{e['low']:+.3f}, {e['high']:+.3f}] {e['verdict']}"


def _outcome(success: bool, category: str | None) -> str:
    return "success" if success else f"failed ({category or '-'})"


def _flip_summary(flips: list[tuple[str, Mapping[str, Any]]]) -> list[str]:
    """The flipped episodes by condition and pair of outcomes: how many, where they part (the
    earliest and latest time), and how many were not compared, by why."""
    pairs: dict[tuple[str, str, str], list[Mapping[str, Any]]] = {}
    for group, f in flips:
        a, b = (_outcome(s, c) for s, c in zip(f["success"], f["failure_category"], strict=True))
        pairs.setdefault((group, a, b), []).append(f.get("divergence") or {})
    lines = []
    for (group, a, b), found in pairs.items():
        times = sorted(d["time"] for d in found if d.get("time") is not None)
        parts = []
        if times:
            span = f"{times[0]:.4g} s" + (f" to {times[-1]:.4g} s" if times[-1] > times[0] else "")
            parts.append(f"{len(times)} part first at t = {span}")
        reasons = Counter(d.get("reason", "-") for d in found if d.get("time") is None)
        parts += [f"{n} {why}" for why, n in reasons.most_common()]
        lines.append(f"  {group}: {a} -> {b}: {len(found)}; {'; '.join(parts)}")
    return lines


def render(diff: Mapping[str, Any]) -> str:
    """The diff as text for a person: what differs in how the runs were made, in what they
    found, and each flipped episode."""
    runs, outputs = diff["runs"], diff["outputs"]
    lines = [f"a: {runs['a']}", f"b: {runs['b']}", ""]
    if "registration" in diff:  # first: it changes what every number below means
        lines += [*registration_lines(diff["registration"]), ""]
    lines.append("How they were made")
    lines += _made_lines(diff["made"])
    lines += ["", "What they found"]
    total = len({rel for rels in outputs.values() for rel in rels})
    broken = _not_as_sealed(outputs)
    n_broken = len(
        {rel for kind, _ in _NOT_AS_SEALED for s in "ab" for rel in outputs.get(f"{kind}_{s}", [])}
    )
    lines.append(
        f"  outputs: {total} sealed; {len(outputs['same'])} the same, "
        f"{len(outputs['same_content'])} the same but for their stamps, "
        f"{len(outputs['recordings'])} recordings (compared through outcomes and trajectories), "
        f"{len(outputs['differ'])} differ" + (f", {n_broken} NOT AS SEALED" if n_broken else "")
    )
    lines += [f"    {line}" for line in broken]
    for key, what in (("differ", "differ"), ("only_a", "only in a"), ("only_b", "only in b")):
        if outputs[key]:
            lines.append(f"    {what}: {_names(outputs[key])}")
    flips = []
    for group, rec in diff["conditions"].items():
        if "only" in rec:
            lines.append(f"  {group}: rolled out in {rec['only']} only")
            continue
        paired = rec["paired"]
        p = paired["p_value"]
        test = f", McNemar exact p = {p:.3g}" if p is not None else ""
        lines.append(
            f"  {group}: {_pct(rec['a'])} -> {_pct(rec['b'])}; on {paired['n']} shared states "
            f"{len(rec['flipped'])} flipped (to failure {paired['only_a']}, to success "
            f"{paired['only_b']}){test}"
        )
        flips += [(group, f) for f in rec["flipped"]]
    for name, rec in diff["effects"].items():
        mark = "  VERDICT CHANGED" if rec["changed"] else ""
        lines.append(f"  effect {name}: {_effect(rec['a'])} -> {_effect(rec['b'])}{mark}")
    lines += [
        "",
        f"Flipped episodes: {len(flips)} (where they part: the first time both recordings "
        f"logged at which a value differs by more than {diff['tolerance']:g})",
    ]
    lines += _flip_summary(flips)
    for group, f in flips[:SHOWN_FLIPS]:
        a, b = (_outcome(s, c) for s, c in zip(f["success"], f["failure_category"], strict=True))
        parts = describe_divergence(f.get("divergence"))
        lines.append(f"  {group} state {f['state_id']}: {a} -> {b}; {parts}")
    if len(flips) > SHOWN_FLIPS:
        lines.append(f"  ... and {len(flips) - SHOWN_FLIPS} more (all in --json)")
    if diff["recording"]:
        lines.append(f"both runs' recordings of them: rerun {diff['recording']}")
    return "\n".join(lines)
