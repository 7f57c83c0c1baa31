"""Provenance stamps: what produced an output file, and how to embed / read that record.

A stamp is a JSON-serialisable dict (see :func:`make_stamp`) recording the rule, the code
(git commit + hash of any uncommitted diff), the config slice, input file hashes, seeds,
library versions and a coarse platform fingerprint.  It deliberately holds nothing private:
no host name, user name, environment variables or home paths.

Every output format carries its stamp in-band:

* Parquet: schema metadata key ``b"mjtrial.provenance"``.
* JSON: top-level key ``"provenance"``.
* Markdown: front matter line ``provenance: <single-line JSON>``.
* PNG: a ``tEXt`` chunk with keyword ``mjtrial.provenance``, just before ``IEND``.
* SVG: a ``<metadata id="mjtrial.provenance">`` element (the JSON as escaped text), first child
  of the root ``<svg>``.
* Rerun ``.rrd``: a recording property, read by :mod:`mjtrial.recording`.

:func:`read_stamp` reads any of them back.
"""

from __future__ import annotations

import hashlib
import importlib.metadata
import importlib.util
import json
import os
import platform
import re
import struct
import zlib
from collections.abc import Iterable, Mapping
from datetime import datetime, timezone
from pathlib import Path
from typing import TYPE_CHECKING, Any
from xml.sax.saxutils import escape as xml_escape

from mjtrial.atomic import atomic_path, write_bytes_atomic, write_json_atomic, write_text_atomic

if TYPE_CHECKING:  # pragma: no cover
    import pyarrow

__all__ = [
    "STAMP_KEY",
    "STAMP_VERSION",
    "MissingStampError",
    "code_hash",
    "config_hash",
    "file_sha256",
    "is_recording_folder",
    "git_state",
    "library_versions",
    "make_stamp",
    "platform_fingerprint",
    "read_stamp",
    "stamp_png_bytes",
    "stamp_parquet_metadata",
    "stamp_svg_text",
    "write_json",
    "write_markdown",
    "write_parquet",
    "write_png",
    "write_svg",
]

STAMP_VERSION = 1
STAMP_KEY = "mjtrial.provenance"
_PARQUET_KEY = STAMP_KEY.encode("ascii")
_PNG_KEYWORD = STAMP_KEY.encode("latin-1")
_PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"
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


class MissingStampError(ValueError):
    """The file exists and has a supported format but carries no mjtrial provenance stamp."""


# --------------------------------------------------------------------------------------------
# Hashes
# --------------------------------------------------------------------------------------------


def code_hash(modules: Iterable[str]) -> str:
    """sha256 over the source files of the named modules (order and duplicates irrelevant).

    Modules are located with :func:`importlib.util.find_spec`, which does not execute the module
    itself (it does import its parent packages).  Each module contributes its name and its
    source bytes, so renaming or editing a module changes the hash.  Meant for Snakemake
    ``params`` so that a real code change reruns a stage.
    """
    if isinstance(modules, str):
        modules = [modules]
    names = sorted(set(modules))
    if not names:
        raise ValueError("code_hash needs at least one module name")
    h = hashlib.sha256()
    for name in names:
        try:
            spec = importlib.util.find_spec(name)
        except (ImportError, ValueError) as exc:
            raise ModuleNotFoundError(f"code_hash: cannot locate module {name!r}: {exc}") from exc
        if spec is None:
            raise ModuleNotFoundError(f"code_hash: no module named {name!r}")
        if not spec.has_location or not spec.origin:
            raise ValueError(
                f"code_hash: module {name!r} has no source file (origin={spec.origin})"
            )
        data = Path(spec.origin).read_bytes()
        h.update(name.encode("utf-8") + b"\0")
        h.update(len(data).to_bytes(8, "big"))
        h.update(data)
    return h.hexdigest()


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


def is_recording_folder(path: str | os.PathLike[str]) -> bool:
    """Whether `path` is a folder of recordings written as one output."""
    path = Path(path)
    return path.is_dir() and (path / RECORDING_FOLDER_BLUEPRINT).is_file()


def file_sha256(path: str | os.PathLike[str]) -> str:
    """sha256 of a file's bytes, read in 1 MiB blocks; of a folder, of its files' names and bytes.

    A folder hashes like the model (`model_sha256`): each file, in name order, as its path
    relative to the folder and its sha256, so a renamed, added or removed file changes it too.
    Hidden files are not its content (Snakemake keeps a ``.snakemake_timestamp`` in folders).
    """
    if Path(path).is_dir():
        folder = Path(path)
        digest = hashlib.sha256()
        files = (q for q in folder.rglob("*") if q.is_file())
        hidden = lambda q: any(part.startswith(".") for part in q.relative_to(folder).parts)  # noqa: E731
        for p in sorted(q for q in files if not hidden(q)):
            digest.update(f"{p.relative_to(folder).as_posix()}\0{file_sha256(p)}\n".encode())
        return digest.hexdigest()
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
    except OSError as exc:
        digest = f"unreadable:{type(exc).__name__}"
    return b"untracked\0" + rel.encode("utf-8", "surrogateescape") + b"\0" + digest.encode()


# Files a MuJoCo model can be built from: the scene, the files it includes, meshes, textures.
MODEL_FILE_SUFFIXES = (".xml", ".stl", ".obj", ".msh", ".skn", ".png")


def model_files(scene: str | os.PathLike[str]) -> list[Path]:
    """Every file in the scene's folder a model can be built from, the scene first.

    A scene includes other files (`<include file=...>`, meshes): hashing the scene alone would
    miss an edit to the model it includes.
    """
    scene = Path(scene)
    others = sorted(
        p
        for p in scene.parent.rglob("*")
        if p.is_file() and p.suffix.lower() in MODEL_FILE_SUFFIXES and p != scene
    )
    return [scene, *others]


def model_sha256(scene: str | os.PathLike[str]) -> str:
    """One hash of all the model's files (`model_files`): names relative to its folder, bytes."""
    scene = Path(scene)
    digest = hashlib.sha256()
    for path in model_files(scene):
        name = path.relative_to(scene.parent).as_posix()
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
    try:
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


def _input_record(path: str | os.PathLike[str], repo_root: Path) -> dict[str, str]:
    p = Path(path)
    shown: str | None = None
    candidates = [(Path(os.path.abspath(p)), Path(os.path.abspath(repo_root)))]
    try:
        candidates.append((p.resolve(), repo_root.resolve()))
    except OSError:
        pass
    for absolute, root in candidates:
        try:
            shown = absolute.relative_to(root).as_posix()
            break
        except ValueError:
            continue
    if shown is None:
        shown = p.name
    return {"path": shown, "sha256": file_sha256(p)}


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
        "mjtrial_stamp": STAMP_VERSION,
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
    return json.loads(json.dumps(stamp, allow_nan=False))


def _stamp_json(stamp: Mapping[str, Any], *, ascii_only: bool = False) -> str:
    """Compact single-line JSON of a stamp (validated to look like one)."""
    if not isinstance(stamp, Mapping) or "mjtrial_stamp" not in stamp:
        raise ValueError(
            "not an mjtrial provenance stamp (missing 'mjtrial_stamp'); use make_stamp"
        )
    return json.dumps(dict(stamp), ensure_ascii=ascii_only, allow_nan=False)


def _parse_stamp(text: str | bytes, path: Path) -> dict[str, Any]:
    try:
        stamp = json.loads(text)
    except ValueError as exc:
        raise ValueError(f"{path}: corrupt mjtrial provenance stamp: {exc}") from exc
    if not isinstance(stamp, dict) or "mjtrial_stamp" not in stamp:
        raise ValueError(f"{path}: corrupt mjtrial provenance stamp (not a stamp object)")
    return stamp


def _missing(path: Path) -> MissingStampError:
    return MissingStampError(f"{path}: no mjtrial provenance stamp")


# --- Parquet ---------------------------------------------------------------------------------


def stamp_parquet_metadata(table: pyarrow.Table, stamp: Mapping[str, Any]) -> pyarrow.Table:
    """Return ``table`` with the stamp added to its schema metadata (other keys kept)."""
    metadata = dict(table.schema.metadata or {})
    metadata[_PARQUET_KEY] = _stamp_json(stamp).encode("utf-8")
    return table.replace_schema_metadata(metadata)


def write_parquet(
    table: pyarrow.Table, path: str | os.PathLike[str], stamp: Mapping[str, Any], **kwargs: Any
) -> None:
    """Atomically write ``table`` (stamped) to ``path``; kwargs go to ``pq.write_table``."""
    import pyarrow.parquet as pq

    stamped = stamp_parquet_metadata(table, stamp)
    with atomic_path(path) as tmp:
        pq.write_table(stamped, tmp, **kwargs)


def _read_parquet_stamp(path: Path) -> dict[str, Any]:
    import pyarrow.parquet as pq

    metadata = pq.read_schema(path).metadata or {}
    raw = metadata.get(_PARQUET_KEY)
    if raw is None:
        raise _missing(path)
    return _parse_stamp(raw, path)


# --- JSON ------------------------------------------------------------------------------------


def write_json(
    obj: Mapping[str, Any], path: str | os.PathLike[str], stamp: Mapping[str, Any]
) -> None:
    """Atomically write ``obj`` with the stamp under top-level key ``"provenance"``.

    ``obj`` is not modified; an existing ``"provenance"`` entry is replaced.
    """
    if not isinstance(obj, Mapping):
        raise TypeError(f"write_json needs a dict-like object, got {type(obj).__name__}")
    _stamp_json(stamp)  # validate
    out = {k: v for k, v in obj.items() if k != "provenance"}
    out["provenance"] = dict(stamp)
    write_json_atomic(path, out)


def _read_json_stamp(path: Path) -> dict[str, Any]:
    with open(path, encoding="utf-8") as fh:
        obj = json.load(fh)
    stamp = obj.get("provenance") if isinstance(obj, dict) else None
    if not isinstance(stamp, dict) or "mjtrial_stamp" not in stamp:
        raise _missing(path)
    return stamp


# --- Markdown --------------------------------------------------------------------------------

_FRONT = "---"
_MD_PREFIX = "provenance:"


def _split_front_matter(text: str) -> tuple[list[str] | None, str]:
    """(front matter lines, body) when ``text`` starts with a ``---`` block, else (None, text)."""
    if text.startswith("\ufeff"):
        text = text[1:]
    lines = text.splitlines(keepends=True)
    if not lines or lines[0].rstrip("\r\n") != _FRONT:
        return None, text
    for i in range(1, len(lines)):
        if lines[i].rstrip("\r\n") == _FRONT:
            front = [ln.rstrip("\r\n") for ln in lines[1:i]]
            return front, "".join(lines[i + 1 :])
    return None, text


def markdown_with_stamp(text: str, stamp: Mapping[str, Any]) -> str:
    """``text`` with a front matter block holding the stamp (merged into existing front matter,
    replacing any previous ``provenance:`` line)."""
    line = f"{_MD_PREFIX} {_stamp_json(stamp, ascii_only=True)}"
    front, body = _split_front_matter(text)
    kept = [ln for ln in (front or []) if not ln.startswith(_MD_PREFIX)]
    return "\n".join([_FRONT, line, *kept, _FRONT]) + "\n" + body


def write_markdown(text: str, path: str | os.PathLike[str], stamp: Mapping[str, Any]) -> None:
    """Atomically write Markdown ``text`` preceded by ``---\\nprovenance: <json>\\n---\\n``."""
    write_text_atomic(path, markdown_with_stamp(text, stamp))


def _read_markdown_stamp(path: Path) -> dict[str, Any]:
    front, _ = _split_front_matter(path.read_text(encoding="utf-8"))
    for ln in front or []:
        if ln.startswith(_MD_PREFIX):
            return _parse_stamp(ln[len(_MD_PREFIX) :].strip(), path)
    raise _missing(path)


# --- PNG -------------------------------------------------------------------------------------


def _png_chunks(png: bytes) -> list[tuple[bytes, bytes, int, int]]:
    """Parse PNG chunks as (type, data, start, end) with CRC checks; raise ValueError if bad."""
    if not png.startswith(_PNG_SIGNATURE):
        raise ValueError("not a PNG file (bad signature)")
    chunks = []
    pos = len(_PNG_SIGNATURE)
    while True:
        if pos + 12 > len(png):
            raise ValueError("truncated PNG (no IEND chunk)")
        (length,) = struct.unpack(">I", png[pos : pos + 4])
        ctype = png[pos + 4 : pos + 8]
        end = pos + 12 + length
        if end > len(png):
            raise ValueError(f"truncated PNG chunk {ctype!r}")
        data = png[pos + 8 : pos + 8 + length]
        (crc,) = struct.unpack(">I", png[pos + 8 + length : end])
        if zlib.crc32(ctype + data) & 0xFFFFFFFF != crc:
            raise ValueError(f"PNG chunk {ctype!r} has a bad CRC")
        chunks.append((ctype, data, pos, end))
        pos = end
        if ctype == b"IEND":
            return chunks


def _png_chunk(ctype: bytes, data: bytes) -> bytes:
    crc = zlib.crc32(ctype + data) & 0xFFFFFFFF
    return struct.pack(">I", len(data)) + ctype + data + struct.pack(">I", crc)


def _png_text_keyword(ctype: bytes, data: bytes) -> bytes | None:
    if ctype in (b"tEXt", b"zTXt", b"iTXt"):
        return data.split(b"\0", 1)[0]
    return None


def stamp_png_bytes(png: bytes, stamp: Mapping[str, Any]) -> bytes:
    """Return ``png`` with a ``tEXt`` chunk ``mjtrial.provenance`` inserted before ``IEND``.

    Any previous ``mjtrial.provenance`` text chunk is removed.  The input is validated (chunk
    CRCs, IEND present); bytes after IEND are kept as they were.
    """
    text = _stamp_json(stamp, ascii_only=True).encode("latin-1")
    chunks = _png_chunks(bytes(png))
    out = [_PNG_SIGNATURE]
    for ctype, data, start, end in chunks:
        if ctype == b"IEND":
            out.append(_png_chunk(b"tEXt", _PNG_KEYWORD + b"\0" + text))
        elif _png_text_keyword(ctype, data) == _PNG_KEYWORD:
            continue
        out.append(png[start:end])
    out.append(png[chunks[-1][3] :])
    return b"".join(out)


def write_png(png_bytes: bytes, path: str | os.PathLike[str], stamp: Mapping[str, Any]) -> None:
    """Atomically write the PNG ``png_bytes`` to ``path`` with the stamp embedded."""
    write_bytes_atomic(path, stamp_png_bytes(png_bytes, stamp))


def _png_text_value(ctype: bytes, data: bytes) -> str:
    _, rest = data.split(b"\0", 1)
    if ctype == b"tEXt":
        return rest.decode("latin-1")
    if ctype == b"zTXt":
        return zlib.decompress(rest[1:]).decode("latin-1")
    # iTXt: compression flag, method, language tag \0, translated keyword \0, text
    flag, rest = rest[0], rest[2:]
    _, _, rest = rest.split(b"\0", 2)
    return (zlib.decompress(rest) if flag else rest).decode("utf-8")


def _read_png_stamp(path: Path) -> dict[str, Any]:
    try:
        chunks = _png_chunks(path.read_bytes())
    except ValueError as exc:
        raise ValueError(f"{path}: {exc}") from exc
    for ctype, data, _, _ in chunks:
        if _png_text_keyword(ctype, data) == _PNG_KEYWORD:
            return _parse_stamp(_png_text_value(ctype, data), path)
    raise _missing(path)


# --- SVG -------------------------------------------------------------------------------------

# An element rather than an XML comment: JSON may contain "--", which a comment cannot hold.
_SVG_STAMP_RE = re.compile(
    r'\s*<metadata id="' + re.escape(STAMP_KEY) + r'">[^<]*</metadata>', re.DOTALL
)
# The root start tag; quoted attribute values may contain ">".
_SVG_ROOT_RE = re.compile(r"""<svg\b(?:[^>"']|"[^"]*"|'[^']*')*>""")
_SVG_NS = "{http://www.w3.org/2000/svg}"


def _svg_root(svg: bytes) -> Any:
    """The parsed root element of an SVG document; ValueError when it is not one."""
    import xml.etree.ElementTree as ET

    try:
        root = ET.fromstring(svg)
    except ET.ParseError as exc:
        raise ValueError(f"not an SVG file (XML parse error: {exc})") from exc
    if root.tag not in ("svg", f"{_SVG_NS}svg"):
        raise ValueError(f"not an SVG file (root element {root.tag!r})")
    return root


def stamp_svg_text(svg: str | bytes, stamp: Mapping[str, Any]) -> str:
    """Return ``svg`` with ``<metadata id="mjtrial.provenance">`` as the root's first child.

    Any previous stamp element is removed; the rest of the document is kept byte for byte.  The
    input must parse as XML with an ``<svg>`` root (a bytes input is decoded as UTF-8).
    """
    text = svg.decode("utf-8") if isinstance(svg, bytes) else str(svg)
    _svg_root(text.encode("utf-8"))
    body = _stamp_json(stamp, ascii_only=True)
    text = _SVG_STAMP_RE.sub("", text)
    match = _SVG_ROOT_RE.search(text)
    if match is None or match.group(0).endswith("/>"):
        raise ValueError("SVG has no root <svg> start tag to hold a stamp")
    element = f'\n <metadata id="{STAMP_KEY}">{xml_escape(body)}</metadata>'
    return text[: match.end()] + element + text[match.end() :]


def write_svg(svg: str | bytes, path: str | os.PathLike[str], stamp: Mapping[str, Any]) -> None:
    """Atomically write the SVG document ``svg`` to ``path`` (UTF-8) with the stamp embedded."""
    write_text_atomic(path, stamp_svg_text(svg, stamp))


def _read_svg_stamp(path: Path) -> dict[str, Any]:
    try:
        root = _svg_root(path.read_bytes())
    except ValueError as exc:
        raise ValueError(f"{path}: {exc}") from exc
    for element in root:
        if element.tag in ("metadata", f"{_SVG_NS}metadata") and element.get("id") == STAMP_KEY:
            return _parse_stamp(element.text or "", path)
    raise _missing(path)


# --- Rerun -----------------------------------------------------------------------------------


def _read_rrd_stamp(path: Path) -> dict[str, Any]:
    try:
        from mjtrial.recording import read_rrd_stamp
    except ImportError as exc:
        raise ImportError(
            f"{path}: reading a stamp from a .rrd file needs mjtrial.recording.read_rrd_stamp, "
            f"which could not be imported ({exc})"
        ) from exc
    stamp = read_rrd_stamp(path)
    if stamp is None:
        raise _missing(path)
    return stamp


# --- Dispatch --------------------------------------------------------------------------------

_READERS = {
    ".parquet": _read_parquet_stamp,
    ".json": _read_json_stamp,
    ".md": _read_markdown_stamp,
    ".png": _read_png_stamp,
    ".svg": _read_svg_stamp,
    ".rrd": _read_rrd_stamp,
}


def read_stamp(path: str | os.PathLike[str]) -> dict[str, Any]:
    """Read the stamp embedded in an output file, dispatching on its suffix.

    Raises :class:`MissingStampError` when the file has no stamp, ``ValueError`` for an
    unsupported suffix or a corrupt file/stamp, ``FileNotFoundError`` when it does not exist.
    """
    path = Path(path)
    if path.is_dir():  # a folder of recordings: each holds the same stamp
        return _read_rrd_stamp(path)
    reader = _READERS.get(path.suffix.lower())
    if reader is None:
        raise ValueError(
            f"{path}: cannot read a provenance stamp from {path.suffix or 'suffix-less'} files "
            f"(supported: {', '.join(sorted(_READERS))})"
        )
    return reader(path)
