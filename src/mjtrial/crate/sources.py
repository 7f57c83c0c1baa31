"""The workflow's sources as they ran, copied into the results folder (`source/`).

A crate's workflow must be a file of the crate (Workflow RO-Crate: the main workflow exists in
the payload), and the crate's root is the results folder, so the crate job copies the files
that define the run there: `mjtrial.files.layout.WORKFLOW_SOURCES` from the working folder, and the
`mjtrial` package that ran (from where Python imports it) as `src/mjtrial/`. The copy is also
what `mjtrial crate --zip` lays out beside the results, so the zip is a checkout that runs.
"""

from __future__ import annotations

import ast
import shutil
from collections.abc import Iterable, Iterator
from pathlib import Path

import mjtrial
from mjtrial import provenance
from mjtrial.files.atomic import atomic_directory, fsync_files
from mjtrial.files.layout import STAGES, WORKFLOW_SOURCES

# Found in a source tree, never part of it.
_SKIPPED_DIRS = ("__pycache__",)
_SKIPPED_SUFFIXES = (".pyc", ".pyo")
# Folders of which the copy keeps only the subfolders the run's jobs read (`source_files`).
_READ_ONLY_IF_USED = ("models", "tasks")
# Files a copy of the workflow without them takes from the package's own repository.
_PROJECT_FILES = ("pyproject.toml", "README.md")


def _files_under(path: Path) -> Iterator[Path]:
    if path.is_file():
        yield path
        return
    for p in sorted(path.rglob("*")):
        rel = p.relative_to(path).parts
        if (
            p.is_file()
            and not any(part.startswith(".") or part in _SKIPPED_DIRS for part in rel)
            and not any(part.endswith(".egg-info") for part in rel)
            and p.suffix not in _SKIPPED_SUFFIXES
        ):
            yield p


def source_files(workdir: Path, read: Iterable[str] = ()) -> dict[str, Path]:
    """What the copy holds: its path in `source/` -> the file it copies.

    `WORKFLOW_SOURCES` from `workdir` (a copy of the workflow without `pyproject.toml` or
    `README.md` takes them from the package's repository, when it has them), the package
    Python imports as `src/mjtrial/`, and the files in `read` (paths relative to `workdir`
    that the jobs read: a model or a task kept outside those folders travels too). Of
    `models/` and `tasks/`, only the folders holding a file in `read` are copied (whole, with
    their READMEs and licences). Hidden files, `__pycache__` and compiled files are left.
    """
    workdir = Path(workdir)
    package = Path(mjtrial.__file__).resolve().parent
    read = list(read)
    # of `models/` and `tasks/`, the folders the jobs read from (robosuite's exported arm
    # model is 45 MB of meshes, which no other run needs); all of them when nothing says what
    # was read
    used = {Path(rel).parts[:2] for rel in read if len(Path(rel).parts) > 2}
    files: dict[str, Path] = {}
    for name in WORKFLOW_SOURCES:
        top = workdir / name
        if not top.exists() and name in _PROJECT_FILES:
            top = mjtrial.REPO_ROOT / name
        if not top.exists():
            continue
        for f in _files_under(top):
            rel = (Path(name) / f.relative_to(top)).as_posix() if top.is_dir() else name
            parts = Path(rel).parts
            if used and name in _READ_ONLY_IF_USED and len(parts) > 2 and parts[:2] not in used:
                continue
            files[rel] = f
    for f in _files_under(package):
        files[(Path("src") / package.name / f.relative_to(package)).as_posix()] = f
    for rel in read:
        if not Path(rel).is_absolute() and ".." not in Path(rel).parts:
            if (workdir / rel).is_file():
                files.setdefault(Path(rel).as_posix(), workdir / rel)
    return dict(sorted(files.items()))


def copy_sources(workdir: Path, output: Path, read: Iterable[str] = ()) -> None:
    """Write the copy of the sources to the folder `output`, atomically (whole or not at all)."""
    files = source_files(workdir, read)
    with atomic_directory(output) as tmp:
        for rel, src in files.items():
            dest = tmp / rel
            dest.parent.mkdir(parents=True, exist_ok=True)
            shutil.copyfile(src, dest)
        fsync_files(tmp / rel for rel in files)  # all on disk before the folder is renamed


def listed_sources(folder: Path) -> dict[str, tuple[str, int]]:
    """Each file of a copy of the sources: its path in the folder -> (sha256, size in bytes).

    Every file but hidden ones (Snakemake's timestamp), as the folder's sha256 counts them
    (`mjtrial.provenance.file_sha256`): a file added to the copy is listed, and seen.
    """
    folder = Path(folder)
    out = {}
    for f in sorted(folder.rglob("*")):
        rel = f.relative_to(folder)
        if f.is_file() and not any(part.startswith(".") for part in rel.parts):
            out[rel.as_posix()] = (provenance.file_sha256(f), f.stat().st_size)
    return out


def stage_scripts(source: Path) -> dict[str, str]:
    """Each stage script's summary line (its docstring's first), read from the copy of the
    sources in `source`, by the script's path."""
    texts = []
    for stage in STAGES.values():
        path = Path(source) / stage.script_path
        if path.is_file():
            texts.append((stage.script_path, path.read_text(encoding="utf-8")))
    return script_summaries(texts)


def script_summaries(texts: Iterable[tuple[str, str]]) -> dict[str, str]:
    """(path, Python source) -> the first line of each module docstring, by path."""
    out = {}
    for path, text in texts:
        try:
            doc = ast.get_docstring(ast.parse(text))
        except SyntaxError:
            doc = None
        if doc:
            out[path] = doc.strip().splitlines()[0]
    return out
