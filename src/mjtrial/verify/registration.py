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
from mjtrial.design.registration import (
    RegistrationError,
    design_record,
    deviations,
    deviations_seen,
    lost_deviation_note,
    problems,
    read,
    stamp_problems,
)
from mjtrial.files.layout import Layout
from mjtrial.verify.chain import OutputResult, Status

RULE = "register"
_SHOWN = 3  # outputs named whose stamps disagree with the registration


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
    # the registration each output was made under (its stamp's): a rewrite since disagrees
    stamps = manifest.get("stamps")
    reasons += stamp_problems(data, stamps if isinstance(stamps, Mapping) else {})[:_SHOWN]
    if isinstance(recorded, Mapping):
        if recorded.get("sha256") != data.get("sha256"):
            reasons.append("the manifest records another registration")
        elif _of_config(recorded.get("deviations")) != _of_config(
            json.loads(json.dumps(found, default=str))
        ) and _current(layout.manifest, repo_root):
            reasons.append(
                "the manifest's deviations are not those recomputed from the config against "
                "the registration"
            )
    if reasons:
        return OutputResult(path, Status.TAMPERED, tuple(reasons), RULE)
    return OutputResult(path, Status.OK, (), RULE)


def _current(path: Path, repo_root: Path) -> bool:
    """Whether every input `path`'s stamp records still has the sha256 it recorded: a manifest
    built before a task or config file changed is stale (the chain says so), and its
    deviations are those of the design it was built with, not a forgery."""
    try:
        inputs = provenance.read_stamp(path).get("inputs", {})
    except (OSError, ValueError):
        return True
    entries = [e for v in inputs.values() for e in (v if isinstance(v, list) else [v])]
    for entry in entries:
        if not isinstance(entry, Mapping) or "path" not in entry or "sha256" not in entry:
            continue
        file = Path(repo_root) / entry["path"]
        if file.is_file() and provenance.file_sha256(file) != entry["sha256"]:
            return False
        if not file.exists():
            return False
    return True


def _of_config(found: Any) -> Any:
    """A deviations list less its changes of the task's files, the model and the policy files:
    those the chain already judges (an edited or added task file, or a contract added beside a
    policy graph, makes every output that read it stale), so a manifest built before one is
    stale, not forged."""
    if not isinstance(found, list):
        return found
    code = ("task_files_sha256", "model_sha256", "policy_files_sha256")
    return [
        c for c in found if not (isinstance(c, Mapping) and str(c.get("key", "")).startswith(code))
    ]


def check_deviations_kept(layout: Layout, *, path: str, repo_root: Path) -> OutputResult | None:
    """`deviations.json` (`path` as the report names it) missing, or without the deviation the
    manifest recorded from it: named with how to restore it (`lost_deviation_note`); else None.
    The manifest's recomputation then differs too, for that reason alone or not."""
    lost = lost_deviation_note(layout)
    if lost is None:
        return None
    status = Status.MISSING if not layout.deviations.exists() else Status.TAMPERED
    return OutputResult(path, status, (lost.replace(f"{repo_root}/", ""),), RULE)
