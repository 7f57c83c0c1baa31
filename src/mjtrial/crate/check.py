"""What `mjtrial verify` checks of a results folder's crate and its copy of the sources.

The crate is the last output: nothing records its sha256 after it, so verify rebuilds it from
the folder (the seals its stamp records, the stamps of every sealed output, the files' sizes,
the copy of the sources) with the same function the crate job used, and compares. The jobs'
times come from Snakemake's records on the machine that ran them, so they are taken from the
crate and checked against the stamps instead (`record.time_problems`). The copy of the sources
is checked against the crate's list and against the code the stamps record.
"""

from __future__ import annotations

import dataclasses
import json
from collections.abc import Iterable, Mapping
from pathlib import Path
from typing import Any

from mjtrial import provenance
from mjtrial.crate.description import DESCRIPTIVE, HOW_TO_SET
from mjtrial.crate.graph import crate_metadata, entity_path
from mjtrial.crate.record import RunRecord, input_records, read_record, time_problems
from mjtrial.crate.sources import stage_scripts
from mjtrial.crate.stamp import graph_entities, read_crate_stamp
from mjtrial.files.layout import Layout

_SHOWN = 3


def _more(items: list[str]) -> str:
    more = f" and {len(items) - _SHOWN} more" if len(items) > _SHOWN else ""
    return "; ".join(items[:_SHOWN]) + more


def covered_seals(crate_stamp: Mapping[str, Any]) -> list[str]:
    """The seals a crate covers (repository-relative), as its stamp records its inputs."""
    return [r["path"] for r in input_records(crate_stamp.get("inputs", {}))]


def recorded_times(entities: Mapping[str, Mapping[str, Any]]) -> dict[str, tuple[Any, Any]]:
    """Each job's start and end as the crate records them, by its stamp's rule."""
    return {
        e["name"]: (e.get("startTime"), e.get("endTime"))
        for i, e in entities.items()
        if i.startswith("#job/") and isinstance(e.get("name"), str)
    }


def listed_sources(
    entities: Mapping[str, Mapping[str, Any]], prefix: str = "source/"
) -> dict[str, tuple[str, int]]:
    """The files of the copy of the sources as the crate lists them: path -> (sha256, size)."""
    listed = {}
    for identifier, entity in entities.items():
        path = entity_path(identifier)
        if path.startswith(prefix) and not path.endswith("/"):
            try:
                size = int(entity.get("contentSize"))
            except (TypeError, ValueError):
                size = -1
            listed[path.removeprefix(prefix)] = (entity.get("sha256"), size)
    return dict(sorted(listed.items()))


def _module_file(name: str, sources: Mapping[str, Any]) -> str | None:
    """The file of a code record's entry in the copy (a script's path, or a module's name)."""
    if "/" in name:
        return name if name in sources else None
    base = "src/" + name.replace(".", "/")
    return next((f for f in (f"{base}.py", f"{base}/__init__.py") if f in sources), None)


def code_problems(
    sources: Mapping[str, tuple[str, int]], stamps: Iterable[Mapping[str, Any]]
) -> list[str]:
    """Files of the copy that are not the code the stamps record having run."""
    problems: dict[str, None] = {}
    for stamp in stamps:
        extra = stamp.get("extra") if isinstance(stamp, Mapping) else None
        code = extra.get("code") if isinstance(extra, Mapping) else None
        for name, sha in (code or {}).items():
            path = _module_file(name, sources)
            if path is None:
                problems.setdefault(f"{name} ({stamp.get('rule')}) is not in source/")
            elif sources[path][0] != sha:
                problems.setdefault(f"source/{path} is not the code {stamp.get('rule')} ran")
    return list(problems)


def _entity_differences(have: Mapping[str, Any], want: Mapping[str, Any]) -> list[str]:
    out = []
    for identifier in sorted(have.keys() | want.keys()):
        a, b = have.get(identifier), want.get(identifier)
        if a == b:
            continue
        if a is None:
            out.append(f"{identifier} is missing")
        elif b is None:
            out.append(f"{identifier} is not the folder's")
        else:
            keys = sorted(k for k in a.keys() | b.keys() if a.get(k) != b.get(k))
            out.append(f"{identifier}: {', '.join(keys)}")
    return out


def crate_differences(
    layout: Layout,
    *,
    repo_root: Path,
    stamps: Mapping[str, Mapping[str, Any]],
) -> dict[str, str]:
    """Why the crate or its copy of the sources is not what the folder gives (repository-
    relative path -> reason); empty when both are. `stamps` are stamps already read (the others
    are read here). The copy must hold the code the stamps of the sealed outputs record.

    Verify calls it only when the stamps judge the crate current, and then every output it
    covers is current too (anything else makes its seal, and so the crate, stale).
    """
    crate, source = layout.crate, layout.source
    rel = {p: provenance.repo_relative(p, repo_root) for p in (crate, source)}
    differs: dict[str, str] = {}
    entities = graph_entities(crate)
    crate_stamp = read_crate_stamp(crate)
    if crate_stamp is None:
        return {rel[crate]: "it carries no stamp"}
    listed = listed_sources(entities)
    record = read_record(
        layout,
        repo_root=repo_root,
        seals=[Path(repo_root) / p for p in covered_seals(crate_stamp)],
        crate_stamp=crate_stamp,
        times=recorded_times(entities),
        stamps=stamps,
    )
    folder = [
        f"source/{p}: " + ("not listed" if p not in listed else "its sha256 differs")
        for p in record.sources
        if listed.get(p, (None,))[0] != record.sources[p][0]
    ] + [f"source/{p}: missing" for p in listed if p not in record.sources]
    code = code_problems(record.sources, [*record.stamps.values(), crate_stamp])
    if folder or code:
        differs[rel[source]] = _more(folder + code)
        # The crate is compared with the copy it lists: an edit to the copy is the copy's.
        listed_digest = _listed_digest(entities, record)
        record = dataclasses.replace(record, sources=listed, source_sha256=listed_digest)
    want = crate_metadata(record, scripts=stage_scripts(source))
    have = json.loads(provenance.read_output_text(crate))
    reasons = []
    if have.get("@context") != want["@context"]:
        reasons.append("its @context differs")
    wanted = {e["@id"]: e for e in want["@graph"]}
    reasons += _entity_differences(entities, wanted)
    if _described_by_hand(entities, wanted):
        reasons.insert(0, f"edited by hand ({HOW_TO_SET})")
    reasons += time_problems(record)
    if reasons:
        differs[rel[crate]] = _more(reasons) + " (file -> recomputed)"
    return differs


def _described_by_hand(
    have: Mapping[str, Mapping[str, Any]], want: Mapping[str, Mapping[str, Any]]
) -> bool:
    """Whether the crate's license, authors or keywords (or a person) are not the config's."""
    root, wanted = have.get("./") or {}, want.get("./") or {}
    if any(root.get(key) != wanted.get(key) for key in DESCRIPTIVE):
        return True
    people = [i for i in have.keys() | want.keys() if have.get(i) != want.get(i)]
    return any("Person" in str((have.get(i) or want.get(i) or {}).get("@type")) for i in people)


def _listed_digest(entities: Mapping[str, Mapping[str, Any]], record: RunRecord) -> str:
    entity = entities.get("source/") or {}
    return str(entity.get("sha256") or record.source_sha256)
