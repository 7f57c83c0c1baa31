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
import json
from collections.abc import Mapping
from functools import cache
from pathlib import Path

from mjtrial import REPO_ROOT
from mjtrial.files import atomic

PACKAGE = "mjtrial"
PACKAGE_DIR = Path(__file__).resolve().parents[1]  # src/mjtrial, this file being in files/


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


Statement = tuple[str, int, tuple[str, ...]]  # (module, level, names); names () for `import`


def import_statements(source: str) -> list[Statement]:
    """Every import statement of `source`, anywhere in it, as written (not yet resolved)."""
    found: list[Statement] = []
    for node in ast.walk(ast.parse(source)):
        if isinstance(node, ast.Import):
            found += [(a.name, 0, ()) for a in node.names]
        elif isinstance(node, ast.ImportFrom):
            found.append((node.module or "", node.level, tuple(a.name for a in node.names)))
    return found


def resolve_imports(statements: list[Statement], *, module: str | None = None) -> set[str]:
    """The `mjtrial` modules that import `statements` name (see `imported_modules`). Resolved
    at each use, never cached: `from mjtrial import x` depends on which module files exist."""
    found: set[str] = set()
    package = None
    if module is not None:
        package = module if _is_package(module) else module.rpartition(".")[0]
    for base, level, names in statements:
        if not names:
            if base.split(".")[0] == PACKAGE:
                found.add(base)
            continue
        if level:
            if package is None:
                continue
            anchor = package.split(".")
            anchor = anchor[: len(anchor) - (level - 1)]
            base = ".".join([*anchor, base] if base else anchor)
        if base.split(".")[0] != PACKAGE:
            continue
        for name in names:
            sub = f"{base}.{name}"
            found.add(sub if module_file(sub) is not None else base)
    return found


def imported_modules(source: str, *, module: str | None = None) -> set[str]:
    """The `mjtrial` modules that `source` imports anywhere in it.

    Args:
      source: Python source text.
      module: the importing module's name, to resolve relative imports (None for a script).

    `from mjtrial import x` names the module `mjtrial.x` when that is a module, else `mjtrial`.
    """
    return resolve_imports(import_statements(source), module=module)


# Each module's import statements by the sha256 of its source, kept between processes: parsing
# every module with `ast` cost about 0.6 s of each Snakemake start (it asks for every stage's
# code hash). A content key cannot go stale; a cache that cannot be read or written is only
# slower.
IMPORTS_CACHE = REPO_ROOT / ".snakemake" / "mjtrial-module-imports.json"


@cache
def _statements_cache() -> dict[str, list[Statement]]:
    try:
        kept = json.loads(IMPORTS_CACHE.read_text(encoding="utf-8"))
        return {k: [(m, lv, tuple(n)) for m, lv, n in v] for k, v in kept.items()}
    except (OSError, ValueError, TypeError):
        return {}


def _source_statements(data: bytes) -> list[Statement]:
    """`import_statements` of a module's bytes, from the cache when it holds them."""
    kept = _statements_cache()
    key = hashlib.sha256(data).hexdigest()
    if key not in kept:
        kept[key] = import_statements(data.decode("utf-8"))
        _unsaved.add(key)
    return kept[key]


_unsaved: set[str] = set()


def _save_statements_cache() -> None:
    if not _unsaved:
        return
    _unsaved.clear()
    try:
        IMPORTS_CACHE.parent.mkdir(exist_ok=True)
        atomic.write_json_atomic(IMPORTS_CACHE, _statements_cache())
    except OSError:
        pass


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
    _save_statements_cache()
    return sorted(seen)


@cache
def _module_imports(file: Path, name: str) -> frozenset[str]:
    """`imported_modules` of one module's file, parsed once per process (Snakemake asks for
    every stage's closure at start-up, and the closures share most modules)."""
    return frozenset(resolve_imports(_source_statements(file.read_bytes()), module=name))


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
