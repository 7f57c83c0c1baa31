"""What a results folder is, before it is verified: a copy of a run recorded under another path,
or a benchmark's folder.

Stamps and seals record paths relative to the repository, so a folder copied or renamed
(`cp -r results/t1 results/t1_cp`, or a copy outside the repository) still names the original's
files: checked in place, every one would be "missing". Its seal says where the run was recorded
(`recorded_as`); verify checks it there, in a view of the checkout with the copy placed at that
path (`placed_as_recorded`): its files against its seal and stamps, its recomputations and
re-simulations with the checkout's code, config, model and task.
"""

from __future__ import annotations

import json
import os
import shutil
import tempfile
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

from mjtrial import provenance
from mjtrial.files.layout import BenchmarkLayout, Layout


def _sealed_outputs(results_dir: Path) -> list[str] | None:
    """The outputs the folder's seal lists (repository-relative), or None without a readable
    seal."""
    try:
        listed = json.loads(provenance.read_output_text(Layout(results_dir).seal))["outputs"]
        return [str(p) for p in listed]
    except (OSError, ValueError, KeyError, TypeError):
        return None


def recorded_as(results_dir: Path, *, repo_root: Path) -> str | None:
    """The folder (repository-relative) where the run in `results_dir` was recorded, when that
    is not where it is now (a copy, a folder renamed since, one outside the repository); None
    when its seal lists this folder's outputs, or there is no readable seal."""
    here = provenance.path_in_repo(results_dir, repo_root)
    outputs = _sealed_outputs(results_dir)
    if outputs is None:
        return None
    if not outputs or (here is not None and any(Path(p).is_relative_to(here) for p in outputs)):
        return None
    recorded = Path(os.path.commonpath(outputs) if len(outputs) > 1 else Path(outputs[0]).parent)
    if recorded.is_absolute() or ".." in recorded.parts or recorded == Path("."):
        return None  # not a record this pipeline writes: checked in place
    return recorded.as_posix()


def _link_or_copy(source: Path, target: Path) -> None:
    try:
        os.link(source, target)
    except OSError:  # another file system
        shutil.copy2(source, target)


def _mirror(source: Path, target: Path, *, skip: str | None = None) -> None:
    """`source`'s files at `target`, linked or copied, so that they resolve inside the view (a
    model or policy file outside the repository is refused); a Python environment (the
    MuJoCo versions' `envs/`) is a symlink, not copied. Hidden files and `__pycache__` are
    left out, and the entry named `skip`."""
    if (source / "pyvenv.cfg").is_file():
        target.symlink_to(source, target_is_directory=True)
        return
    target.mkdir()
    for entry in sorted(source.iterdir()):
        if entry.name.startswith(".") or entry.name in ("__pycache__", skip):
            continue
        if entry.is_symlink():
            (target / entry.name).symlink_to(os.readlink(entry))
        elif entry.is_dir():
            _mirror(entry, target / entry.name)
        elif entry.is_file():
            _link_or_copy(entry, target / entry.name)


@contextmanager
def placed_as_recorded(results_dir: Path, *, recorded: str, repo_root: Path) -> Iterator[Path]:
    """A temporary view of the checkout `repo_root` (`_mirror`; not the folder holding
    `recorded`, `results/`) with `results_dir` placed at `recorded` (a symlink, read as a
    symlinked results folder is): yields the view's root."""
    top = Path(recorded).parts[0]
    with tempfile.TemporaryDirectory(prefix="mjtrial-verify-copy-") as tmp:
        view = Path(tmp).resolve() / "checkout"
        _mirror(Path(repo_root), view, skip=top)
        place = view / recorded
        place.parent.mkdir(parents=True, exist_ok=True)
        place.symlink_to(Path(results_dir).resolve(), target_is_directory=True)
        yield view


def copied_from(results_dir: Path, *, repo_root: Path) -> str | None:
    """One line when `results_dir` holds a run whose seal lists its outputs under another
    folder (a copy, or a folder renamed since): what the folder is and what it was recorded
    as; None when the seal lists this folder's (or there is no readable seal)."""
    here = provenance.path_in_repo(results_dir, repo_root)
    outputs = _sealed_outputs(results_dir)
    if outputs is None:
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
