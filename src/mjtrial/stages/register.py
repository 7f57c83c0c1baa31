"""The register job: the design registered once, after the states job's checks and before the
first evaluation rollout (`mjtrial.design.registration`)."""

from __future__ import annotations

import logging
from collections.abc import Mapping
from pathlib import Path
from typing import Any

from mjtrial.design.registration import ensure_registered
from mjtrial.files.layout import Layout
from mjtrial.files.safekeeping import Snapshot

log = logging.getLogger("mjtrial")


def register_design(*, config: Mapping[str, Any], output: Path, repo_root: Path) -> None:
    """Register the design unless it is (`output`, the run's registration). A registration
    Snakemake removed to rerun the job (`--forceall`) is put back from the run's snapshot
    (`safekeeping`), never made anew; the log says which."""
    existed = output.exists()
    layout = Layout.of(config["experiment"])
    snapshot = Snapshot(layout.root, logs=layout.logs_dir, workdir=Path(repo_root))
    saved = snapshot.saved(layout.registration)
    data = ensure_registered(config, layout=layout, repo_root=repo_root, saved=saved)
    current = data["current"]
    done = "put back" if saved is not None and not existed else "registered"
    log.info(
        "register: %s %s: %s, design sha256 %s",
        done,
        output,
        current["registered_utc"],
        current["design_sha256"],
    )
