"""The crate's own stamp, carried inside the crate, and the readers that find it.

The metadata file of an RO-Crate is JSON-LD in flattened form (`@context` and `@graph` only),
so its stamp cannot be a top-level `provenance` key as in the other JSON outputs. It is an
entity of the graph instead: a `PropertyValue` named `mjtrial.provenance` whose value is the
stamp's JSON, among the `object`s of the action that wrote the crate (the crate job: its
config slice and its stamp are what it was run with). The copy of the workflow's sources that
the same job writes (`source/`) answers with the same stamp.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

from mjtrial import provenance
from mjtrial.files.layout import CRATE_FILE, Layout
from mjtrial.provenance.formats import STAMP_KEY

# The @id of the stamp's entity in the crate's graph.
STAMP_ID = "#mjtrial-provenance"


def stamp_entity(stamp: dict[str, Any]) -> dict[str, Any]:
    """The stamp as the properties of its `PropertyValue` (the @id is `STAMP_ID`)."""
    if not provenance.is_stamp(stamp):
        raise ValueError("not an mjtrial provenance stamp (missing 'mjtrial_stamp')")
    return {
        "@type": "PropertyValue",
        "name": STAMP_KEY,
        "description": (
            "The provenance stamp of this crate and of source/, as mjtrial writes one into "
            "every output (`mjtrial provenance ro-crate-metadata.json` prints it)."
        ),
        "value": json.dumps(stamp, sort_keys=True, ensure_ascii=True, allow_nan=False),
    }


def graph_entities(crate: Path) -> dict[str, dict[str, Any]]:
    """The crate's entities by @id; ValueError when the file is not an RO-Crate's metadata."""
    try:
        document = json.loads(provenance.read_output_text(crate))
    except (UnicodeDecodeError, json.JSONDecodeError) as err:
        raise ValueError(f"{crate}: not readable JSON ({err})") from err
    graph = document.get("@graph") if isinstance(document, dict) else None
    if not isinstance(graph, list):
        raise ValueError(f"{crate}: not RO-Crate metadata (no @graph list)")
    return {e["@id"]: e for e in graph if isinstance(e, dict) and isinstance(e.get("@id"), str)}


def read_crate_stamp(crate: Path) -> dict[str, Any] | None:
    """The stamp a crate carries, or None when it carries none."""
    entity = graph_entities(crate).get(STAMP_ID)
    if entity is None or entity.get("name") != STAMP_KEY:
        return None
    try:
        stamp = json.loads(entity.get("value"))
    except (TypeError, ValueError) as err:
        raise ValueError(f"{crate}: corrupt mjtrial provenance stamp: {err}") from err
    if not provenance.is_stamp(stamp):
        raise ValueError(f"{crate}: corrupt mjtrial provenance stamp (not a stamp object)")
    return stamp


def is_source_folder(path: Path) -> bool:
    """Whether `path` is the crate's copy of the workflow's sources in a results folder (one
    that holds a crate or a seal)."""
    path = Path(path)
    layout = Layout(path.parent)
    return (
        path == layout.source
        and path.is_dir()
        and (layout.crate.is_file() or layout.seal.is_file())
    )


def read_source_stamp(folder: Path) -> dict[str, Any] | None:
    """The stamp of the copy of the sources: the crate's, which the same job wrote."""
    crate = Path(folder).parent / CRATE_FILE
    if not crate.is_file():
        raise ValueError(f"its stamp is the crate's, and {CRATE_FILE} is missing")
    return read_crate_stamp(crate)


def register_readers() -> None:
    """Let `mjtrial.provenance.read_stamp` read the crate, `source/` and the files in it."""
    provenance.register_reader(CRATE_FILE, read_crate_stamp)
    provenance.register_folder_reader(is_source_folder, read_source_stamp)
