"""What a results folder is, before it is verified: a copy of a run recorded under another path,
or a benchmark's folder.

Stamps and seals record paths relative to the repository, so a folder copied or renamed
(`cp -r results/t1 results/t1_cp`) still names the original's files: checked in place, every
one would be "missing". Its seal says where the run was recorded; verify says so in one line.
"""

from __future__ import annotations

import json
import os
from pathlib import Path

from mjtrial import provenance
from mjtrial.layout import BenchmarkLayout, Layout


def copied_from(results_dir: Path, *, repo_root: Path) -> str | None:
    """One line when `results_dir` holds a run whose seal lists its outputs under another
    folder (a copy, or a folder renamed since): what the folder is and what it was recorded
    as; None when the seal lists this folder's (or there is no readable seal)."""
    here = provenance.path_in_repo(results_dir, repo_root)
    try:
        listed = json.loads(provenance.read_output_text(Layout(results_dir).seal))["outputs"]
        outputs = [str(p) for p in listed]
    except (OSError, ValueError, KeyError, TypeError):
        return None
    if here is None or not outputs or any(Path(p).is_relative_to(here) for p in outputs):
        return None
    recorded = os.path.commonpath(outputs) if len(outputs) > 1 else Path(outputs[0]).parent
    return (
        f"{here} is a copy of the run recorded as {Path(recorded).as_posix()} (its seal lists "
        f"the outputs there; stamps record paths in the repository): verify "
        f"{Path(recorded).as_posix()}, or rebuild this folder with snakemake"
    )


def looks_like_benchmark(results_dir: Path) -> bool:
    """Whether `results_dir` holds a benchmark's outputs (its trainings or its summary's
    stamp), whatever config is at hand."""
    layout = BenchmarkLayout(results_dir)
    if (results_dir / "training").is_dir():
        return True
    try:
        return provenance.read_stamp(layout.summary).get("rule") == "benchmark"
    except (OSError, ValueError):
        return False
