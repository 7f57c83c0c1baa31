"""Loading a task: from a file path, an importable module name, or an entry point of the group
`mjtrial.tasks`; one import at a time.
"""

from __future__ import annotations

import importlib
import importlib.metadata
import importlib.util
import os
import sys
import threading
from dataclasses import replace
from pathlib import Path
from typing import Any

from mjtrial.task.declare import TaskError
from mjtrial.task.definition import Task

ENTRY_POINT_GROUP = "mjtrial.tasks"

# One task import at a time: Snakemake's in-process jobs are threads sharing `sys.modules`.
_IMPORT_LOCK = threading.RLock()
# --------------------------------------------------------------------------------------------
# Loading
# --------------------------------------------------------------------------------------------


def _from_file(path: Path) -> Task:
    """Import a task file afresh. In a folder with an `__init__.py` (a task package, whose
    siblings it imports relatively: `from .protocol import ...`), the folder is imported as a
    package of a name unique to its path, so two copies of one task never share modules and an
    edit is always seen; else the file alone is imported."""
    name = f"mjtrial_task_{abs(hash(path.resolve()))}"
    with _IMPORT_LOCK:
        try:
            if (path.parent / "__init__.py").is_file():
                # A copy: another thread (`import_in_background`) may be importing meanwhile,
                # and iterating `sys.modules` as it grows raises RuntimeError.
                loaded = sys.modules.copy()
                for cached in [m for m in loaded if m == name or m.startswith(f"{name}.")]:
                    del sys.modules[cached]
                package_spec = importlib.util.spec_from_file_location(
                    name, path.parent / "__init__.py", submodule_search_locations=[str(path.parent)]
                )
                package = importlib.util.module_from_spec(package_spec)
                sys.modules[name] = package
                package_spec.loader.exec_module(package)
                name = f"{name}.{path.stem}"
            spec = importlib.util.spec_from_file_location(name, path)
            if spec is None or spec.loader is None:
                raise TaskError(f"{path}: not a Python file")
            module = importlib.util.module_from_spec(spec)
            sys.modules[name] = module
            spec.loader.exec_module(module)
        except TaskError:
            raise
        except Exception as err:  # noqa: BLE001 - any error in the user's file is one line
            sys.modules.pop(name, None)
            raise TaskError(f"{path}: the task file raised {type(err).__name__}: {err}") from None
    return _task_of(module, str(path), path.parent)


def task_files(task_file: Path) -> list[Path]:
    """What stamps record of a task named by path and an edit reruns: every file of its folder
    and below (data the task reads included), less caches and hidden files, sorted."""
    folder = Path(task_file).parent
    if (folder / "Snakefile").exists():
        raise TaskError(f"{task_file}: expected a folder of its own (its files are its inputs)")
    files = {p.relative_to(folder) for p in folder.rglob("*") if p.is_file()}
    cached = {p for p in files if any(x == "__pycache__" or x[0] == "." for x in p.parts)}
    return sorted(folder / p for p in files - cached)


def _task_of(module: Any, where: str, folder: Path) -> Task:
    task = getattr(module, "TASK", None)
    if not isinstance(task, Task):
        raise TaskError(f"{where}: expected a module-level TASK = mjtrial.task.Task(...)")
    model = Path(task.model)
    model = Path(os.path.normpath(model if model.is_absolute() else folder / model))
    source = Path(module.__file__) if getattr(module, "__file__", None) else None
    if not task.series:
        raise TaskError(f"{source or where}: series: expected at least one Series to record")
    names = [s.name for s in task.series]
    if task.trace is not None and task.trace not in names:
        raise TaskError(f"{source or where}: trace: expected one of the series {names}")
    measures = [m.name for m in task.measures]
    if task.margin is not None and task.margin.measure not in measures:
        raise TaskError(
            f"{source or where}: margin: expected the name of one of the measures {measures}, "
            f"got {task.margin.measure!r}"
        )
    return replace(task, model=model, source=source)


def load_task(reference: str | Path, *, repo_root: Path = Path(".")) -> Task:
    """The task a config names: a `.py` path (relative to `repo_root`), an entry point name of
    the group `mjtrial.tasks`, or an importable module name defining `TASK`."""
    text = str(reference)
    if text.endswith(".py"):
        path = Path(text) if Path(text).is_absolute() else Path(repo_root) / text
        if not path.is_file():
            raise TaskError(f"{text}: task file not found")
        task_files(path)
        return _from_file(path)
    for entry in importlib.metadata.entry_points(group=ENTRY_POINT_GROUP):
        if entry.name == text:
            module = entry.load()
            return _task_of(module, f"entry point {text}", Path(module.__file__).parent)
    try:
        module = importlib.import_module(text)
    except ImportError as err:
        raise TaskError(
            f"{text}: no task file, entry point ({ENTRY_POINT_GROUP}) or module of that name "
            f"({err})"
        ) from None
    return _task_of(module, text, Path(module.__file__).parent)
