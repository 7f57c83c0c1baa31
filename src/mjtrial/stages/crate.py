"""The crate stage: the results folder as a Provenance Run Crate (`mjtrial.crate`)."""

from __future__ import annotations

import dataclasses
import logging
import time
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

from mjtrial import REPO_ROOT, provenance
from mjtrial.crate.graph import crate_metadata
from mjtrial.crate.record import (
    iso_time,
    read_inputs,
    read_record,
    running_job_start,
    sealed_stamps,
    snakemake_times,
)
from mjtrial.crate.sources import copy_sources, stage_scripts
from mjtrial.files.atomic import write_json_atomic
from mjtrial.files.layout import Layout
from mjtrial.stages.stamping import make_stage_stamp

log = logging.getLogger("mjtrial")


def write_crate(
    *,
    seals: Sequence[Path],
    crate_slice: Mapping[str, Any],
    output: Path,
    source_output: Path,
    rule: str = "crate",
    repo_root: Path = REPO_ROOT,
) -> dict[str, Any]:
    """Copy the workflow's sources to `source_output` and write `output`, the crate of every
    run sealed in `seals` (the built-in experiment's seal, and each study's that is there).

    The jobs' times come from Snakemake's records in `repo_root` (the working folder).
    """
    layout = Layout(Path(output).parent)
    started = running_job_start(repo_root, provenance.repo_relative(output, repo_root))
    stamps = sealed_stamps(seals, repo_root=repo_root)
    results = provenance.repo_relative(layout.root, repo_root)
    read = [p for p in read_inputs(stamps) if not p.startswith(f"{results}/")]
    copy_sources(repo_root, source_output, read=read)
    stamp = make_stage_stamp(rule, dict(crate_slice), {"seals": list(seals)}, repo_root=repo_root)
    record = read_record(layout, repo_root=repo_root, seals=seals, crate_stamp=stamp, stamps=stamps)
    times = snakemake_times(repo_root, record.jobs())
    times["crate"] = (started, iso_time(time.time()))
    record = dataclasses.replace(record, times=times)
    metadata = crate_metadata(record, scripts=stage_scripts(source_output))
    write_json_atomic(output, metadata)
    log.info(
        "crate: %d jobs, %d files -> %s",
        len(record.jobs()) + 1,
        len(record.outputs) + len(record.sources),
        output,
    )
    return metadata
