"""Which contract a policy file reads now, against the one a stamp records it ran with.

A policy file's contract is `<file>.yaml` beside it, else its folder's `policy.yaml`
(`policy_file.contract_path`); a stamp records both files it ran with (`inputs.policy`, path
and sha256). A contract edited in place is an input changed; a `<file>.yaml` added beside a
graph that ran with its folder's `policy.yaml` (or removed) changes which file is read, and
only this check sees it.
"""

from __future__ import annotations

import posixpath
from collections.abc import Iterable
from pathlib import Path
from typing import Any

from mjtrial import provenance
from mjtrial.policy_files.file import FOLDER_CONTRACT, contract_path


def contract_change(records: Iterable[Any], *, repo_root: Path) -> str | None:
    """Why the policy files of one stamp input (`records`: its graph and contract records) no
    longer read the contract they ran with, naming both contracts; None when they do."""
    files = [r.get("path") for r in records if isinstance(r, dict)]
    files = [f for f in files if isinstance(f, str)]
    for graph in (f for f in files if f.endswith(".onnx")):
        now = provenance.repo_relative(contract_path(Path(repo_root) / graph), repo_root)
        if now in files:
            continue
        folder = posixpath.dirname(graph)
        used = [f for f in files if f.endswith(".yaml") and posixpath.dirname(f) == folder]
        was = used[0] if used else "another contract"
        if posixpath.basename(now) != FOLDER_CONTRACT:
            return (
                f"contract changed: {graph} now reads {now}, which shadows {was} it ran with "
                f"(remove {posixpath.basename(now)} or rebuild)"
            )
        return f"contract changed: {graph} now reads {now}, not {was} it ran with"
    return None
