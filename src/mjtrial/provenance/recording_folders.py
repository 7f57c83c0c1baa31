"""What a folder of recordings (one output, `stamp.is_recording_folder`) lacks of what its
record (`recordings.json`) names, and the command that rebuilds it. Snakemake sees the folder,
not its files: a file deleted inside it is "Nothing to be done", so the workflow's load and
`mjtrial verify` name it. Light on purpose: the workflow's load imports it (no rerun)."""

from __future__ import annotations

import json
import os
from pathlib import Path

from mjtrial.provenance.stamp import RECORDING_FOLDER_STAMP, is_recording_folder


def rebuild_hint(path: str | os.PathLike[str]) -> str:
    """How to rebuild a file of a condition's folder of recordings (a folder written as one
    output, which Snakemake does not look into): "" for a file elsewhere."""
    folder = Path(path).parent
    if not is_recording_folder(folder):
        return ""
    return f"; `snakemake -c2 -R {folder}` rebuilds its folder and what was made from it"


def damaged_folders(results: str | os.PathLike[str]) -> list[str]:
    """`folder_problem` of each folder of recordings under `results` (hidden folders, a
    snapshot's, left out) that lacks a file its record names, in path order."""
    results = Path(results)
    found = []
    for record in sorted(results.rglob(RECORDING_FOLDER_STAMP)):
        if any(part.startswith(".") for part in record.relative_to(results).parts):
            continue
        problem = folder_problem(record.parent)
        if problem:
            found.append(problem)
    return found


def folder_problem(folder: str | os.PathLike[str]) -> str | None:
    """What a condition's folder of recordings lacks of what its `recordings.json` records
    (its mesh store; its episodes' files), with the command that rebuilds it; None if
    nothing. A deleted file there leaves the folder, which is the output Snakemake sees."""
    folder = Path(folder)
    try:
        contents = json.loads((folder / RECORDING_FOLDER_STAMP).read_text())
    except (OSError, ValueError):
        return None  # no record: the folder's stamp check says so
    missing = []
    meshes = contents.get("meshes")
    if isinstance(meshes, str) and not (folder / meshes).is_file():
        missing.append(f"its mesh store {meshes}")
    recorded = contents.get("recordings")
    found = sum(1 for p in folder.glob("*.rrd") if p.is_file() and p.name != meshes)
    if isinstance(recorded, int) and found < recorded:
        missing.append(f"{recorded - found} of its {recorded} episodes' recordings")
    if not missing:
        return None
    return (
        f"{folder}: {' and '.join(missing)} missing ({RECORDING_FOLDER_STAMP} records "
        f"{'them' if len(missing) > 1 else 'it'}){rebuild_hint(folder / RECORDING_FOLDER_STAMP)}"
    )
