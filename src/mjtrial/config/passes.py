"""A config check's pass, remembered per version of everything the check reads.

The check simulates before any work: every condition's nominal episode through the task's
code, each state parameter at its ends, each variant. That is 1 to 10 s of CPU for the
built-in experiments, and Snakemake pays it at every start, a dry run's included. The
workflow's Snakemake process remembers a pass in `CONFIG_CHECKS` (`remember_passes`),
under a key that hashes what the check reads: the config, the task's files, the model's files,
every condition's policy files (each by resolved path and content), the package's own files
and schemas, and the versions of the libraries it simulates and validates with. The same key
again skips the check; any other runs it. A task named by module (code of an installed
package, whose edits no file here shows) is checked every time, and so is every call outside
the workflow (`mjtrial verify` checks for itself).
"""

from __future__ import annotations

import hashlib
import json
import os
import sys
from collections.abc import Mapping
from importlib import metadata
from pathlib import Path
from typing import Any

import mujoco

import mjtrial
from mjtrial.files.atomic import write_text_atomic
from mjtrial.provenance import file_sha256
from mjtrial.provenance.model_closure import model_closure
from mjtrial.task import task_files

# The libraries whose behaviour a check's verdict depends on (MuJoCo's own version is read
# from the module: a variant's environment runs another).
LIBRARIES = ("numpy", "scipy", "jsonschema", "PyYAML", "onnx", "onnxruntime")

# Where the workflow keeps them: in Snakemake's folder of the working folder, beside the compiled
# models (`layout.COMPILED_MODELS`); deleting it costs a check. Here, not in `layout`: every
# stage's code hash covers `layout`, and a path only Snakemake's process reads is no reason to
# rebuild a user's results.
CONFIG_CHECKS = Path(".snakemake") / "mjtrial-config-checks"

_KEEP_IN: list[Path] = []


def remember_passes(folder: str | os.PathLike[str] | None) -> None:
    """Make `check_config` remember its passes in `folder` in this process (None: no longer)."""
    _KEEP_IN[:] = [] if folder is None else [Path(folder)]


def keeping() -> bool:
    """Whether this process remembers passes."""
    return bool(_KEEP_IN)


def _files(paths: list[Path]) -> list[list[str]]:
    """Each file as its resolved path and its sha256 ("missing" when it is not a file)."""
    return [[str(p.resolve()), file_sha256(p) if p.is_file() else "missing"] for p in paths]


def _package_files() -> list[list[str]]:
    package = Path(mjtrial.__file__).parent
    files = sorted(
        p
        for p in package.rglob("*")
        if p.is_file() and "__pycache__" not in p.parts and p.suffix != ".pyc"
    )
    return [[p.relative_to(package).as_posix(), file_sha256(p)] for p in files]


def _version(name: str) -> str:
    try:
        return metadata.version(name)
    except metadata.PackageNotFoundError:
        return "absent"


def check_key(
    config: Mapping[str, Any], *, repo_root: Path, schemas: Path, policies: list[Path] | None
) -> str | None:
    """The key of a check of `config` in `repo_root`, or None when it cannot have one: a task
    not named by path, a task, model or policy file that cannot be read (the check says why)."""
    task, model = config.get("task"), config.get("model")
    if policies is None or not (
        isinstance(task, str) and task.endswith(".py") and isinstance(model, str)
    ):
        return None
    root = Path(repo_root).resolve()
    task_file, model_file = root / task, root / model
    if not (task_file.is_file() and model_file.is_file()):
        return None
    try:
        inputs = {
            "config": json.loads(json.dumps(config, sort_keys=True, default=str)),
            "repo_root": str(root),
            "task": _files(task_files(task_file)),
            "model": _files(model_closure(model_file)),
            "policies": _files(policies),
            "schemas": _files(sorted(p for p in Path(schemas).rglob("*") if p.is_file())),
            "package": _package_files(),
            "versions": {
                "python": sys.version,
                "mujoco": mujoco.__version__,
                **{name: _version(name) for name in LIBRARIES},
            },
        }
    except Exception:  # noqa: BLE001 - anything unreadable: no key, the check runs and says why
        return None
    text = json.dumps(inputs, sort_keys=True, separators=(",", ":"))
    return hashlib.sha256(text.encode()).hexdigest()


def passed(key: str | None) -> bool:
    """Whether a check with this key passed before, in the folder `remember_passes` named."""
    return key is not None and keeping() and (_KEEP_IN[0] / key).is_file()


def remember(key: str | None) -> None:
    """Remember a pass (nothing without a key or a folder)."""
    if key is None or not _KEEP_IN:
        return
    _KEEP_IN[0].mkdir(parents=True, exist_ok=True)
    write_text_atomic(_KEEP_IN[0] / key, "passed\n")
