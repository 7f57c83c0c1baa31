"""Building a provenance stamp: the record of what produced one output file.

A stamp is a JSON-serialisable dict (see :func:`make_stamp`) recording the rule, the code
(git commit + hash of any uncommitted diff), the config slice, input file hashes, seeds,
library versions and a coarse platform fingerprint.  It deliberately holds nothing private:
no host name, user name, environment variables or home paths.  How a stamp travels inside each
file format is :mod:`mjtrial.provenance.formats`.
"""

from __future__ import annotations

import hashlib
import importlib.metadata
import json
import os
import platform
import stat
from collections.abc import Iterable, Mapping
from contextvars import ContextVar
from datetime import datetime, timezone
from pathlib import Path
from typing import Any

from mjtrial.provenance.model_closure import model_closure

__all__ = [
    "RECORDING_FOLDER_BLUEPRINT",
    "STAMP_VERSION",
    "REGISTRATION_SHA256",
    "NotRegularFileError",
    "check_regular",
    "config_hash",
    "file_sha256",
    "git_state",
    "is_recording_folder",
    "is_stamp",
    "library_versions",
    "make_stamp",
    "model_files",
    "model_sha256",
    "platform_fingerprint",
]

STAMP_VERSION = 1
# The registration the running job was made under (its sha256, `registration.entry_sha256`),
# set around the job's stage by `workflow_script.run_job`: every stamp the job makes records
# it, so a registration rewritten later disagrees with the outputs made before it.
REGISTRATION_SHA256: ContextVar[str | None] = ContextVar("registration_sha256", default=None)
# The field that marks a dict as a stamp, holding STAMP_VERSION.
_VERSION_FIELD = "mjtrial_stamp"
_BLOCK = 1 << 20

# Distributions whose versions go into every stamp: stamp key -> distribution name.
_DISTRIBUTIONS = {
    "mujoco": "mujoco",
    "numpy": "numpy",
    "snakemake": "snakemake",
    "rerun-sdk": "rerun-sdk",
    "gitpython": "GitPython",
    "pyarrow": "pyarrow",
    "mjtrial": "mjtrial",
}

# /proc/cpuinfo flags that change floating-point results or vectorised code paths.
_FP_FLAGS = frozenset(
    {
        "sse",
        "sse2",
        "sse3",
        "ssse3",
        "sse4_1",
        "sse4_2",
        "avx",
        "avx2",
        "fma",
        "avx512f",
        "avx512dq",
        "avx512vl",
        "avx512bw",
        "f16c",
    }
)

# Untracked files under these top-level directories are outputs, not code.
_IGNORED_UNTRACKED_DIRS = ("results", ".snakemake")


# --------------------------------------------------------------------------------------------
# Hashes
# --------------------------------------------------------------------------------------------


def _canonical_json(obj: Any) -> bytes:
    return json.dumps(
        obj, sort_keys=True, separators=(",", ":"), ensure_ascii=False, allow_nan=False
    ).encode("utf-8")


def config_hash(slice: Any) -> str:
    """sha256 of the canonical JSON (sorted keys, no whitespace, UTF-8) of ``slice``."""
    return hashlib.sha256(_canonical_json(slice)).hexdigest()


# An output made of many files, one rerun recording each (`mjtrial.recording`), is a folder
# holding this blueprint beside its .rrd files; it is hashed and stamped as one output.
RECORDING_FOLDER_BLUEPRINT = "blueprint.rbl"


# Each folder of recordings also holds its stamp in a small JSON file, so that reading it needs
# no .rrd parsing, and a folder that recorded no episode (recording.episodes: failed) has one.
RECORDING_FOLDER_STAMP = "recordings.json"


def is_recording_folder(path: str | os.PathLike[str]) -> bool:
    """Whether `path` is a folder of recordings written as one output."""
    path = Path(path)
    return path.is_dir() and (path / RECORDING_FOLDER_BLUEPRINT).is_file()


# Folder digests already computed in this process, by the folder and its files' names, sizes,
# modification times and inodes. The failures, report, manifest and seal jobs run in
# Snakemake's one process and each records every shard's recordings folder (3.2 GB at
# N = 20,000): the bytes are read once, not four times. An edit changes a file's time and
# reads the folder again; `mjtrial verify` runs in a process of its own and reads everything.
_FOLDER_DIGESTS: dict[tuple[str, str], str] = {}


def _folder_signature(folder: Path, files: list[Path]) -> str:
    h = hashlib.sha256()
    for p in files:
        st = p.stat()
        h.update(
            f"{p.relative_to(folder).as_posix()}\0{st.st_size}\0{st.st_mtime_ns}\0{st.st_ino}\n".encode()
        )
    return h.hexdigest()


class NotRegularFileError(ValueError):
    """A path that is neither a regular file nor a folder: a FIFO, a socket or a device."""


_KINDS = {stat.S_IFIFO: "a FIFO", stat.S_IFSOCK: "a socket", stat.S_IFCHR: "a character device"}
_KINDS[stat.S_IFBLK] = "a block device"


def check_regular(path: str | os.PathLike[str], *, folder: bool = True) -> None:
    """Refuse, before it is opened, what mjtrial must never read as an output or an input: a
    FIFO blocks until something writes to it, a device never ends. `folder`: a folder is
    accepted too. Symlinks are followed; FileNotFoundError when `path` does not exist."""
    mode = os.stat(path).st_mode
    if stat.S_ISREG(mode) or (folder and stat.S_ISDIR(mode)):
        return
    kind = "a folder" if stat.S_ISDIR(mode) else _KINDS.get(stat.S_IFMT(mode), "a special file")
    expected = "a regular file or a folder" if folder else "a regular file"
    raise NotRegularFileError(f"{path}: {kind}; expected {expected}")


def _is_content_file(path: Path) -> bool:
    """Whether a folder's entry is one of its files (a broken symlink is not); a FIFO, socket or
    device is refused (`check_regular`)."""
    if path.is_dir() or not path.exists():
        return False
    check_regular(path, folder=False)
    return True


def file_sha256(path: str | os.PathLike[str]) -> str:
    """sha256 of a file's bytes, read in 1 MiB blocks; of a folder, of its files' names and bytes.

    A folder hashes like the model (`model_sha256`): each file, in name order, as its path
    relative to the folder and its sha256, so a renamed, added or removed file changes it too.
    Hidden files are not its content (Snakemake keeps a ``.snakemake_timestamp`` in folders).
    NotRegularFileError for a FIFO, socket or device, at `path` or in its folder.
    """
    check_regular(path)
    if Path(path).is_dir():
        folder = Path(path)
        hidden = lambda q: any(part.startswith(".") for part in q.relative_to(folder).parts)  # noqa: E731
        listed = sorted(q for q in folder.rglob("*") if not hidden(q) and _is_content_file(q))
        key = (str(folder.resolve()), _folder_signature(folder, listed))
        if key not in _FOLDER_DIGESTS:
            digest = hashlib.sha256()
            for p in listed:
                digest.update(f"{p.relative_to(folder).as_posix()}\0{file_sha256(p)}\n".encode())
            _FOLDER_DIGESTS[key] = digest.hexdigest()
        return _FOLDER_DIGESTS[key]
    h = hashlib.sha256()
    with open(path, "rb") as fh:
        while block := fh.read(_BLOCK):
            h.update(block)
    return h.hexdigest()


# --------------------------------------------------------------------------------------------
# Git
# --------------------------------------------------------------------------------------------


def _unavailable(reason: str) -> dict[str, Any]:
    return {"available": False, "reason": " ".join(reason.split())}


def _scrub(text: str, *paths: str | os.PathLike[str]) -> str:
    """One line of ``text`` with the given paths and the home directory removed."""
    line = " ".join(str(text).split())
    for p in paths:
        if p and str(p) not in ("/", "."):
            line = line.replace(str(p), "<repo>")
    home = str(Path.home())
    if home not in ("/", ""):
        line = line.replace(home, "~")
    return line


def _untracked_hash_entry(root: Path, rel: str) -> bytes:
    p = root / rel
    try:
        if p.is_symlink():
            digest = "symlink:" + hashlib.sha256(os.readlink(p).encode()).hexdigest()
        else:
            digest = file_sha256(p)
    except (OSError, NotRegularFileError) as exc:
        digest = f"unreadable:{type(exc).__name__}"
    return b"untracked\0" + rel.encode("utf-8", "surrogateescape") + b"\0" + digest.encode()


def model_files(scene: str | os.PathLike[str]) -> list[Path]:
    """Every file MuJoCo builds the model from, the scene first (`model_closure`): the files it
    includes, meshes, textures, height fields and skins, wherever they are. Paths are given as
    the scene's is (relative to the same folder when the scene's path is relative)."""
    scene = Path(scene)
    origin = Path.cwd() if not scene.is_absolute() else None
    closure = model_closure(scene)
    if origin is None:
        return closure
    return [scene, *(Path(os.path.relpath(p, origin)) for p in closure[1:])]


def model_sha256(scene: str | os.PathLike[str]) -> str:
    """One hash of all the model's files (`model_files`): names relative to the scene's folder,
    bytes."""
    scene = Path(scene)
    digest = hashlib.sha256()
    for path in model_files(scene):
        name = Path(os.path.relpath(path, scene.parent)).as_posix()
        digest.update(f"{name}\0{file_sha256(path)}\n".encode())
    return digest.hexdigest()


def git_state(repo_dir: str | os.PathLike[str]) -> dict[str, Any]:
    """State of the git checkout containing ``repo_dir``; never raises.

    Returns ``{"available": True, "commit", "branch", "dirty", "diff_sha256"}`` where
    ``branch`` is None on a detached HEAD and ``diff_sha256`` hashes ``git diff HEAD`` (staged
    and unstaged changes to tracked files) plus the names and content hashes of untracked files,
    or is None when the checkout is clean.  Untracked files that are gitignored or live under
    ``results/`` or ``.snakemake/`` are not considered.  ``dirty`` is True exactly when
    ``diff_sha256`` is not None.

    When there is no usable repository (not a repo, path missing, git not installed, no commits
    yet, bare repo, any git failure) returns ``{"available": False, "reason": "<one line>"}``.
    """
    try:  # imported here: GitPython raises ImportError when no git executable is installed
        import git
    except ImportError as exc:  # GitPython missing, or it found no git executable at import
        return _unavailable(f"gitpython/git unavailable: {type(exc).__name__}")

    try:
        repo = git.Repo(repo_dir, search_parent_directories=True)
    except git.NoSuchPathError:
        return _unavailable("repo_dir does not exist")
    except git.InvalidGitRepositoryError:
        return _unavailable("not inside a git repository")
    except git.GitCommandNotFound:
        return _unavailable("git executable not found")
    except Exception as exc:  # noqa: BLE001 - provenance must never break a job
        return _unavailable(f"cannot open git repository: {type(exc).__name__}")

    try:
        return _git_state_of(repo, Path(repo_dir))
    except git.GitCommandNotFound:
        return _unavailable("git executable not found")
    except Exception as exc:  # noqa: BLE001
        msg = _scrub(str(exc), repo_dir, getattr(repo, "working_tree_dir", None) or "")
        return _unavailable(f"git error: {type(exc).__name__}: {msg}"[:300])
    finally:
        repo.close()


def _git_state_of(repo: Any, repo_dir: Path) -> dict[str, Any]:
    if repo.bare or not repo.working_tree_dir:
        return _unavailable("bare repository (no working tree)")
    if not repo.head.is_valid():
        return _unavailable("git repository has no commits yet")

    commit = repo.head.commit.hexsha
    branch = None if repo.head.is_detached else repo.active_branch.name

    # Raw bytes of `git diff HEAD`; flags make it independent of user diff configuration and
    # sensitive to binary content.
    diff = repo.git.diff(
        "HEAD", "--no-color", "--no-ext-diff", "--no-textconv", "--binary", stdout_as_string=False
    )

    root = Path(repo.working_tree_dir)
    prefixes = [f"{d}/" for d in _IGNORED_UNTRACKED_DIRS]
    try:
        sub = repo_dir.resolve().relative_to(root.resolve()).as_posix()
    except (OSError, ValueError):
        sub = "."
    if sub != ".":
        prefixes += [f"{sub}/{d}/" for d in _IGNORED_UNTRACKED_DIRS]
    untracked = sorted(
        f for f in repo.untracked_files if not any(f.startswith(p) for p in prefixes)
    )

    if not diff.strip() and not untracked:
        diff_sha = None
    else:
        h = hashlib.sha256(diff)
        for rel in untracked:
            h.update(b"\0" + _untracked_hash_entry(root, rel))
        diff_sha = h.hexdigest()

    return {
        "available": True,
        "commit": commit,
        "branch": branch,
        "dirty": diff_sha is not None,
        "diff_sha256": diff_sha,
    }


# --------------------------------------------------------------------------------------------
# Environment
# --------------------------------------------------------------------------------------------


def library_versions() -> dict[str, str | None]:
    """Versions of Python and the libraries that shape results; None for a missing one."""
    versions: dict[str, str | None] = {"python": platform.python_version()}
    for key, dist in _DISTRIBUTIONS.items():
        try:
            versions[key] = importlib.metadata.version(dist)
        except Exception:  # noqa: BLE001 - PackageNotFoundError or broken metadata
            versions[key] = None
    return versions


def _read_cpuinfo() -> tuple[str | None, list[str]]:
    """(model name, flags) of the first processor in /proc/cpuinfo, or (None, [])."""
    try:
        text = Path("/proc/cpuinfo").read_text(encoding="utf-8", errors="replace")
    except OSError:
        return None, []
    model: str | None = None
    flags: list[str] | None = None
    for line in text.splitlines():
        key, sep, value = line.partition(":")
        if not sep:
            continue
        key = key.strip().lower()
        if key == "model name" and model is None:
            model = value.strip() or None
        elif key in ("flags", "features") and flags is None:
            flags = value.split()
        if model is not None and flags is not None:
            break
    return model, flags or []


def platform_fingerprint() -> dict[str, Any]:
    """Coarse, non-identifying description of the machine (no host or user names)."""
    model, flags = _read_cpuinfo()
    # Linux reports SSE3 as "pni" (Prescott New Instructions), never as "sse3".
    flags = [*flags, "sse3"] if "pni" in flags else flags
    if model is None:
        model = platform.processor() or None
    return {
        "system": platform.system(),
        "machine": platform.machine(),
        "python_implementation": platform.python_implementation(),
        "cpu_model": model,
        "cpu_flags_fp": sorted(_FP_FLAGS.intersection(flags)),
        "ncpu": os.cpu_count(),
    }


# --------------------------------------------------------------------------------------------
# Stamps
# --------------------------------------------------------------------------------------------


def _utc_now() -> str:
    return datetime.now(timezone.utc).strftime("%Y-%m-%dT%H:%M:%SZ")


def repo_relative(path: str | os.PathLike[str], repo_root: Path) -> str:
    """How a stamp names a file: relative to the repository as the path is written (through
    a symlinked results folder), else as resolved, else its name alone."""
    return path_in_repo(path, repo_root) or Path(path).name


def path_in_repo(path: str | os.PathLike[str], repo_root: Path) -> str | None:
    """`path` relative to the repository, as written or else as resolved; None if outside."""
    p = Path(path)
    candidates = [(Path(os.path.abspath(p)), Path(os.path.abspath(repo_root)))]
    try:
        candidates.append((p.resolve(), Path(repo_root).resolve()))
    except OSError:
        pass
    for absolute, root in candidates:
        try:
            return absolute.relative_to(root).as_posix()
        except ValueError:
            continue
    return None


def _input_record(path: str | os.PathLike[str], repo_root: Path) -> dict[str, str]:
    return {"path": repo_relative(path, repo_root), "sha256": file_sha256(path)}


def make_stamp(
    *,
    rule: str,
    config_slice: Any,
    inputs: Mapping[str, str | os.PathLike[str] | Iterable[str | os.PathLike[str]]],
    seeds: Mapping[str, int] | None = None,
    repo_dir: str | os.PathLike[str],
    extra: Mapping[str, Any] | None = None,
) -> dict[str, Any]:
    """Build the provenance stamp for one output.

    ``inputs`` maps names to a path or a list of paths (Snakemake named inputs may be lists);
    each path is recorded relative to ``repo_dir`` (POSIX) when inside it, else by basename
    only, with its sha256.  The result is normalised through JSON, so it compares equal to the
    stamp read back from any output format; a non-JSON-able ``config_slice``/``extra`` raises.
    """
    root = Path(repo_dir)
    recorded_inputs: dict[str, Any] = {}
    for name, value in inputs.items():
        if isinstance(value, (str, os.PathLike)):
            recorded_inputs[str(name)] = _input_record(value, root)
        else:
            recorded_inputs[str(name)] = [_input_record(v, root) for v in value]

    stamp = {
        _VERSION_FIELD: STAMP_VERSION,
        "rule": rule,
        "created_utc": _utc_now(),
        "git": git_state(root),
        "versions": library_versions(),
        "config_slice_sha256": config_hash(config_slice),
        "config_slice": config_slice,
        "inputs": recorded_inputs,
        "seeds": {str(k): int(v) for k, v in (seeds or {}).items()},
        "platform": platform_fingerprint(),
        "extra": dict(extra or {}),
    }
    registered = REGISTRATION_SHA256.get()
    if registered is not None:
        stamp["registration_sha256"] = registered
    return json.loads(json.dumps(stamp, allow_nan=False))


def is_stamp(obj: Any) -> bool:
    """Whether ``obj`` is a stamp as :func:`make_stamp` builds them (a dict with its version)."""
    return isinstance(obj, Mapping) and _VERSION_FIELD in obj
