"""What a crate says of its results beyond the run: the license, the authors, the keywords.

They are the config's `provenance` section (`license`, `authors`, `keywords`), in the crate
job's config slice, so they are set before the crate is written and recorded in its stamp:
`mjtrial verify` rebuilds the crate from the folder and compares all of it, and a hand edit
of the crate is `tampered` like any other, and `mjtrial crate --zip` refuses it. Changing
the authors or keywords in the config reruns the crate alone; the license, which the manifest
records too, reruns the manifest, report, seal and crate; none reruns a rollout.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

# The root's properties the config's provenance section sets, and how a reader sets them.
DESCRIPTIVE = ("license", "author", "keywords")
HOW_TO_SET = (
    "the crate's license, authors and keywords are provenance.license, provenance.authors "
    "and provenance.keywords in the config: set them there and run snakemake -c2"
)


def crate_description(config: Mapping[str, Any]) -> dict[str, Any]:
    """The crate's config slice from a (validated) config: the license (None: none chosen),
    and the authors and keywords when the config gives them (a config without them gives the
    slice, and so the crate, it always gave)."""
    section = config.get("provenance") or {}
    description: dict[str, Any] = {"license": section.get("license")}
    for key in ("authors", "keywords"):
        if section.get(key):
            description[key] = section[key]
    return description
