"""What code a stage runs, computed from its imports: the stage's code hash.

A stage's code is its workflow script plus every `mjtrial` module the script imports, directly
or through other `mjtrial` modules (imports inside functions count too), plus the packages that
hold them (their `__init__` runs on import). The list is read from the source with `ast`, never
kept by hand, so it cannot go stale. A stage's stamp records the sha256 of each of these files,
and its Snakemake params the digest of all of them: an edit reruns exactly the stages whose
scripts reach the edited module, while a `touch`, a checkout or a copy that leaves the content
alone reruns nothing.
"""

from __future__ import annotations

import ast
import hashlib
from collections.abc import Mapping
from functools import cache
from pathlib import Path

from mjtrial import REPO_ROOT

PACKAGE = "mjtrial"
PACKAGE_DIR = Path(__file__).resolve().parent


def module_file(name: str) -> Path | None:
    """The source file of module `name` of this package, or None if there is none."""
    parts = name.split(".")
    if parts[0] != PACKAGE:
        return None
    base = PACKAGE_DIR.joinpath(*parts[1:])
    for candidate in (base / "__init__.py", base.with_suffix(".py")):
        if candidate.is_file():
            return candidate
    return None


def _is_package(name: str) -> bool:
    file = module_file(name)
    return file is not None and file.name == "__init__.py"


def imported_modules(source: str, *, module: str | None = None) -> set[str]:
    """The `mjtrial` modules that `source` imports anywhere in it.

    Args:
      source: Python source text.
      module: the importing module's name, to resolve relative imports (None for a script).

    `from mjtrial import x` names the module `mjtrial.x` when that is a module, else `mjtrial`.
    """
    found: set[str] = set()
    package = None
    if module is not None:
        package = module if _is_package(module) else module.rpartition(".")[0]
    for node in ast.walk(ast.parse(source)):
        if isinstance(node, ast.Import):
            found.update(a.name for a in node.names if a.name.split(".")[0] == PACKAGE)
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                if package is None:
                    continue
                anchor = package.split(".")
                anchor = anchor[: len(anchor) - (node.level - 1)]
                base = ".".join([*anchor, base] if base else anchor)
            if base.split(".")[0] != PACKAGE:
                continue
            for alias in node.names:
                sub = f"{base}.{alias.name}"
                found.add(sub if module_file(sub) is not None else base)
    return found


def _with_parents(name: str) -> list[str]:
    parts = name.split(".")
    return [".".join(parts[:i]) for i in range(1, len(parts) + 1)]


def module_closure(roots: set[str]) -> list[str]:
    """`roots` and every `mjtrial` module they import, transitively, with their packages."""
    seen: set[str] = set()
    todo = [p for r in roots for p in _with_parents(r)]
    while todo:
        name = todo.pop()
        if name in seen:
            continue
        file = module_file(name)
        if file is None:
            raise ModuleNotFoundError(f"{name}: no such module in {PACKAGE_DIR}")
        seen.add(name)
        for imported in _module_imports(file, name):
            todo += _with_parents(imported)
    return sorted(seen)


@cache
def _module_imports(file: Path, name: str) -> frozenset[str]:
    """`imported_modules` of one module's file, parsed once per process (Snakemake asks for
    every stage's closure at start-up, and the closures share most modules)."""
    return frozenset(imported_modules(file.read_text(encoding="utf-8"), module=name))


def _sha256(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def script_code(script: str | Path, *, repo_root: Path = REPO_ROOT) -> dict[str, str]:
    """sha256 of a workflow script and of every package module it runs, by name.

    Args:
      script: the script's path, relative to `repo_root` (as recorded) or absolute.

    Returns:
      `{script path: sha256, module name: sha256, ...}`, sorted by key.
    """
    path = Path(script) if Path(script).is_absolute() else repo_root / script
    code = {Path(script).as_posix(): _sha256(path)}
    for name in module_closure(imported_modules(path.read_text(encoding="utf-8"))):
        code[name] = _sha256(module_file(name))  # type: ignore[arg-type]
    return dict(sorted(code.items()))


def code_digest(code: Mapping[str, str]) -> str:
    """One sha256 over a `script_code` record (names and hashes), for Snakemake params."""
    h = hashlib.sha256()
    for name, digest in sorted(code.items()):
        h.update(f"{name}\0{digest}\n".encode())
    return h.hexdigest()


def changed_code(old: Mapping[str, str], new: Mapping[str, str]) -> list[str]:
    """The files of a stage's code that were added, removed or edited between two records."""
    return sorted(k for k in old.keys() | new.keys() if old.get(k) != new.get(k))
