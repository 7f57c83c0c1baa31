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


def seal_outputs(
    *, outputs: Sequence[Path], output: Path, rule: str = "seal", repo_root: Path = REPO_ROOT
) -> dict[str, Any]:
    """Write `seal.json`: `{"outputs": {path: sha256}}`, stamped with the same records.

    `rule` is the job's: `seal`, or `seal:<study>` for a study's seal (`seal_<study>.json`), so
    that each seal's stamp names the job that wrote it.
    """
    stamp = make_stage_stamp(rule, {}, {p.as_posix(): p for p in outputs}, repo_root=repo_root)
    sealed = {record["path"]: record["sha256"] for record in stamp["inputs"].values()}
    provenance.write_json({"outputs": sealed}, output, stamp)
    log.info("seal: %d outputs -> %s", len(sealed), output)
    return sealed
