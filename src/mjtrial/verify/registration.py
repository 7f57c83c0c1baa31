"""`mjtrial verify` on the registered design: the file is what it says (each registration's
design hash, the history's hash), the seal's sha256 of it is its own, the deviations noted
beside it can be read, and the manifest's deviations are those recomputed from the config
against the registration (the manifest's recomputation checks when they were noted)."""

from __future__ import annotations

import json
from collections.abc import Mapping
from pathlib import Path
from typing import Any

from mjtrial import provenance
from mjtrial.layout import Layout
from mjtrial.registration import (
    RegistrationError,
    design_record,
    deviations,
    deviations_seen,
    problems,
    read,
)
from mjtrial.verify.chain import OutputResult, Status

RULE = "register"


def _json(path: Path) -> dict[str, Any] | None:
    try:
        loaded = json.loads(provenance.read_output_text(path))
    except (OSError, ValueError):
        return None
    return loaded if isinstance(loaded, dict) else None


def check_registration(
    layout: Layout,
    config: Mapping[str, Any],
    *,
    path: str,
    repo_root: Path,
) -> OutputResult | None:
    """The registration's verdict (`path` as the report names it); None when there is none
    and nothing records one."""
    manifest = _json(layout.manifest) or {}
    recorded = manifest.get("registration")
    try:
        data = read(layout.registration)
    except RegistrationError as err:
        return OutputResult(
            path, Status.TAMPERED, (str(err).removeprefix(f"{layout.registration}: "),), RULE
        )
    if data is None:
        return (
            OutputResult(path, Status.MISSING, ("the manifest records it",), RULE)
            if recorded
            else None
        )
    reasons = problems(data)
    seal = _json(layout.seal) or {}
    sealed = (seal.get("registration") or {}).get("sha256")
    now_sha = provenance.file_sha256(layout.registration)
    found = deviations(data, design_record(config, repo_root=repo_root))
    if sealed is not None and sealed != now_sha:
        reasons.append("its sha256 is not the one the seal recorded")
    try:
        deviations_seen(layout)
    except RegistrationError as err:
        reasons.append(str(err).removeprefix(f"{layout.root}/"))
    if isinstance(recorded, Mapping):
        if recorded.get("sha256") != data.get("sha256"):
            reasons.append("the manifest records another registration")
        elif recorded.get("deviations") != json.loads(json.dumps(found, default=str)):
            reasons.append(
                "the manifest's deviations are not those recomputed from the config against "
                "the registration"
            )
    if reasons:
        return OutputResult(path, Status.TAMPERED, tuple(reasons), RULE)
    return OutputResult(path, Status.OK, (), RULE)
