"""The JSON schemas shipped with the package (the config's, a policy file's contract's, a
benchmark's), parsed once per process. Here, not in `mjtrial.config`: a rollout reads a
contract's schema, and importing the config package would put the whole config check in the
rollout's code hash (`mjtrial.files.codehash`), so that an edit of the check reran every
rollout."""

from __future__ import annotations

import copy
import functools
from pathlib import Path
from typing import Any

import yaml

# libyaml's parser where PyYAML was built with it (the wheels are): the same documents in a
# sixth of the pure-Python parser's time, which every Snakemake start and verify paid.
FAST_LOADER = getattr(yaml, "CSafeLoader", yaml.SafeLoader)


def packaged_schema(path: Path) -> dict[str, Any]:
    """The schema in `path`, parsed once per process (a fresh copy each call: a task extends
    the config's schema in place)."""
    return copy.deepcopy(_parsed(Path(path)))


@functools.cache
def _parsed(path: Path) -> dict[str, Any]:
    return yaml.load(path.read_text(encoding="utf-8"), Loader=FAST_LOADER)
