"""The seal: the sha256 of every output, report and figures included, in one stamped file.

An output's own sha256 is otherwise recorded only by the outputs built from it, which leaves
the last ones (the report and its figures, the files that go into a paper) unchecked. The seal
is built from all of them, so its stamp records each one's sha256, and `mjtrial verify` sees
an edit to any of them.
"""

from __future__ import annotations

import logging
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from mjtrial import REPO_ROOT, provenance
from mjtrial.stages.stamping import make_stage_stamp

log = logging.getLogger("mjtrial")
REGISTRATION_KEY = "registration"


def seal_outputs(
    *,
    outputs: Sequence[Path],
    output: Path,
    rule: str = "seal",
    repo_root: Path = REPO_ROOT,
    registration: Path | None = None,
) -> dict[str, Any]:
    """Write `seal.json`: `{"outputs": {path: sha256}}`, stamped with the same records.

    `rule` is the job's: `seal`, or `seal:<study>` for a study's seal (`seal_<study>.json`), so
    that each seal's stamp names the job that wrote it. `registration`: the registered design
    (`mjtrial.design.registration`), sealed under `registration` beside the outputs (no job
    wrote it).
    """
    inputs = {p.as_posix(): p for p in outputs}
    if registration is not None:
        inputs[REGISTRATION_KEY] = registration
    stamp = make_stage_stamp(rule, {}, inputs, repo_root=repo_root)
    sealed = {
        record["path"]: record["sha256"]
        for key, record in stamp["inputs"].items()
        if key != REGISTRATION_KEY
    }
    record = {"outputs": sealed}
    if registration is not None:
        record[REGISTRATION_KEY] = stamp["inputs"][REGISTRATION_KEY]
    provenance.write_json(record, output, stamp)
    log.info("seal: %d outputs -> %s", len(sealed), output)
    return sealed
