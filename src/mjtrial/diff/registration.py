"""The registered designs of two runs, compared first: a registration that changed between
them changes what either run's results mean, before any number does."""

from __future__ import annotations

import json
from collections.abc import Mapping
from typing import Any

from mjtrial.design.registration import changes
from mjtrial.diff.source import Run


def _registration(run: Run) -> tuple[dict[str, Any] | None, list[str]]:
    """A run's current registration (from its file) and the keys its manifest records as
    deviations from it."""
    data = run.json(run.layout.registration.name)
    manifest = run.json(run.layout.manifest.name) or {}
    recorded = manifest.get("registration") or {}
    deviations = [c["key"] for c in recorded.get("deviations", [])]
    return (data.get("current") if data else None), deviations


# What records when (and so carries the time): a registration's times, its sha256s (each
# taken over its time) and the witness of the results (another build's results' hashes).
_WHEN = ("registered_utc", "superseded_utc", "sha256")


def _times(run: Run) -> list[str]:
    """Every time the run's registration file records, as the file and the report write it."""
    data = run.json(run.layout.registration.name) or {}
    entries = [data.get("current") or {}, *(data.get("earlier") or [])]
    found = {str(e[k]) for e in entries if isinstance(e, Mapping) for k in _WHEN[:2] if k in e}
    return sorted(found | {t.replace("T", " ").removesuffix("Z") + " UTC" for t in found})


def _timeless(record: Any) -> Any:
    """A registration record (the file's, or the manifest's) less what records when."""
    if isinstance(record, Mapping):
        return {k: _timeless(v) for k, v in record.items() if k not in _WHEN}
    if isinstance(record, list):
        return [_timeless(v) for v in record]
    return record


def without_registration_time(run: Run, rel: str, content: bytes) -> bytes:
    """An output's content (less its stamp) less when its design was registered: the
    registration file and the manifest's record of it less their times and the sha256s taken
    over them, a report's text with the times written as `<registered>`. Two builds of one
    commit registered at two times; the design registered is compared as before."""
    layout = run.layout
    if rel in (layout.registration.name, layout.manifest.name):
        obj = json.loads(content)
        if rel == layout.registration.name:
            obj = _timeless(obj)
        elif isinstance(obj.get("registration"), Mapping):
            obj["registration"] = _timeless(obj["registration"])
        return json.dumps(obj, sort_keys=True).encode()
    if rel.endswith(".md"):
        text = content.decode("utf-8", errors="replace")
        for when in sorted(_times(run), key=len, reverse=True):
            text = text.replace(when, "<registered>")
        return text.encode()
    return content


def compare_registrations(a: Run, b: Run) -> dict[str, Any]:
    """`a`, `b`: each run's registration (time, design sha256) or None; `changes`: every key of
    the registered design that differs (registered in a, registered in b); each run's recorded
    `deviations` (keys)."""
    (ra, da), (rb, db) = _registration(a), _registration(b)

    def brief(r: Mapping[str, Any] | None) -> dict[str, Any] | None:
        return (
            None
            if r is None
            else {
                "registered_utc": r["registered_utc"],
                "design_sha256": r["design_sha256"],
                "reason": r.get("reason"),
            }
        )

    found = (
        changes(ra["design"], rb["design"])
        if ra is not None and rb is not None and ra["design_sha256"] != rb["design_sha256"]
        else []
    )
    for change in found:
        change["key"] = change["key"].removeprefix("sections.")
    return {
        "a": brief(ra),
        "b": brief(rb),
        "changed": (ra is None) != (rb is None)
        or (ra is not None and ra["design_sha256"] != rb["design_sha256"]),
        "changes": [{"key": c["key"], "a": c["registered"], "b": c["now"]} for c in found],
        "deviations": {"a": da, "b": db},
    }


def registration_lines(record: Mapping[str, Any]) -> list[str]:
    """The diff's first section."""
    a, b = record["a"], record["b"]
    if a is None and b is None:
        return ["Registration", "  neither run is registered"]
    if a is None or b is None:
        which = "a" if a is not None else "b"
        return ["Registration", f"  only {which} is registered"]
    lines = ["Registration"]
    if a["design_sha256"] == b["design_sha256"]:
        lines.append(f"  the same registered design ({a['design_sha256'][:12]})")
    else:
        lines.append(
            f"  REGISTERED DESIGN CHANGED: {a['registered_utc']} ({a['design_sha256'][:12]}) -> "
            f"{b['registered_utc']} ({b['design_sha256'][:12]})"
        )
        lines += [f"    {c['key']}: {c['a']!r} -> {c['b']!r}" for c in record["changes"]]
    for side in ("a", "b"):
        keys = record["deviations"][side]
        if keys:
            lines.append(f"  {side} deviates from its registration: {', '.join(keys)}")
    return lines
