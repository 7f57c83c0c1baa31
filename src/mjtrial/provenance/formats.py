"""A stamp inside each output format: the writers, the readers, and `read_stamp`.

Every output format carries its stamp in-band:

* Parquet: schema metadata key ``b"mjtrial.provenance"``.
* JSON: top-level key ``"provenance"``.
* Markdown: front matter line ``provenance: <single-line JSON>``.
* PNG: a text chunk with keyword ``mjtrial.provenance`` (written through matplotlib's
  ``savefig(metadata=...)``, read with Pillow).
* SVG: a ``<metadata id="mjtrial.provenance">`` element (the JSON as escaped text), first child
  of the root ``<svg>``.
* A job's log (``.log``): its first line, ``# mjtrial.provenance: <single-line JSON>``.
* Rerun ``.rrd``, a file or a folder of them: a recording property. Its reader lives in
  :mod:`mjtrial.recording`, which registers it here when imported (:func:`register_reader`);
  the first read imports it.
* A run's RO-Crate (``ro-crate-metadata.json``): an entity of its graph, read by
  :mod:`mjtrial.crate`, which registers that reader by the file's name.

:func:`read_stamp` reads any of them back with the reader registered for the file's name or
suffix. A file with no stamp of its own inside a folder written as one output (a shard's
``blueprint.rbl``, a file of the crate's copy of the sources) answers with the folder's stamp.
"""

from __future__ import annotations

import importlib
import io
import json
import os
import re
import xml.etree.ElementTree as ET
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import TYPE_CHECKING, Any
from xml.sax.saxutils import escape as xml_escape

from mjtrial.files.atomic import atomic_path, write_json_atomic, write_text_atomic
from mjtrial.provenance.stamp import check_regular, is_recording_folder, is_stamp

if TYPE_CHECKING:  # pragma: no cover
    import pyarrow
    from matplotlib.figure import Figure

__all__ = [
    "STAMP_KEY",
    "MissingStampError",
    "is_folder_output",
    "StampReader",
    "log_stamp_line",
    "markdown_with_stamp",
    "read_stamp",
    "register_folder_reader",
    "register_reader",
    "write_figure",
    "write_json",
    "write_markdown",
    "write_parquet",
    "write_svg",
]

# The name a stamp goes by inside a file: Parquet metadata key, PNG keyword, SVG element id.
STAMP_KEY = "mjtrial.provenance"

# Reads the stamp of one file: the stamp, or None when the file carries none; ValueError when
# the file is corrupt.
StampReader = Callable[[Path], "dict[str, Any] | None"]


class MissingStampError(ValueError):
    """The file exists and has a supported format but carries no mjtrial provenance stamp."""


def _stamp_json(stamp: Mapping[str, Any], *, ascii_only: bool = False) -> str:
    """Compact single-line JSON of a stamp (validated to look like one)."""
    if not is_stamp(stamp):
        raise ValueError(
            "not an mjtrial provenance stamp (missing 'mjtrial_stamp'); use make_stamp"
        )
    return json.dumps(dict(stamp), ensure_ascii=ascii_only, allow_nan=False)


def _parse_stamp(text: str | bytes, path: Path) -> dict[str, Any]:
    try:
        stamp = json.loads(text)
    except ValueError as exc:
        raise ValueError(f"{path}: corrupt mjtrial provenance stamp: {exc}") from exc
    if not isinstance(stamp, dict) or not is_stamp(stamp):
        raise ValueError(f"{path}: corrupt mjtrial provenance stamp (not a stamp object)")
    return stamp


# --- Parquet ---------------------------------------------------------------------------------

_PARQUET_KEY = STAMP_KEY.encode("ascii")


def write_parquet(
    table: pyarrow.Table, path: str | os.PathLike[str], stamp: Mapping[str, Any], **kwargs: Any
) -> None:
    """Atomically write ``table`` (stamped) to ``path``; kwargs go to ``pq.write_table``.

    The stamp joins the table's schema metadata (other keys kept, ``table`` not modified).
    """
    # pyarrow.parquet takes ~0.2 s to import; only the stages that write Parquet pay it.
    import pyarrow.parquet as pq

    metadata = {**(table.schema.metadata or {}), _PARQUET_KEY: _stamp_json(stamp).encode()}
    with atomic_path(path) as tmp:
        pq.write_table(table.replace_schema_metadata(metadata), tmp, **kwargs)


def _read_parquet_stamp(path: Path) -> dict[str, Any] | None:
    import pyarrow.parquet as pq  # slow import, see write_parquet

    raw = (pq.read_schema(path).metadata or {}).get(_PARQUET_KEY)
    return None if raw is None else _parse_stamp(raw, path)


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


def _read_json_stamp(path: Path) -> dict[str, Any] | None:
    with open(path, encoding="utf-8") as fh:
        obj = json.load(fh)
    stamp = obj.get("provenance") if isinstance(obj, dict) else None
    return stamp if isinstance(stamp, dict) and is_stamp(stamp) else None


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


def _read_markdown_stamp(path: Path) -> dict[str, Any] | None:
    front, _ = _split_front_matter(path.read_text(encoding="utf-8"))
    for ln in front or []:
        if ln.startswith(_MD_PREFIX):
            return _parse_stamp(ln[len(_MD_PREFIX) :].strip(), path)
    return None


# --- Figures: PNG and SVG --------------------------------------------------------------------


def write_figure(
    fig: Figure, path: str | os.PathLike[str], stamp: Mapping[str, Any], **savefig_kwargs: Any
) -> None:
    """Atomically save ``fig`` to ``path`` as PNG or SVG, by suffix, with the stamp embedded.

    ``savefig_kwargs`` go to ``fig.savefig`` (``dpi``, ``metadata``, ...; not ``format``, which
    the suffix sets). A PNG gets the stamp as one more entry of savefig's ``metadata``: a text
    chunk of ASCII JSON. An SVG gets it as its own ``<metadata>`` element: matplotlib's SVG
    writer takes only Dublin Core keys, where the stamp would pose as the description.
    """
    path = Path(path)
    text = _stamp_json(stamp, ascii_only=True)
    if path.suffix.lower() == ".png":
        metadata = {**(savefig_kwargs.pop("metadata", None) or {}), STAMP_KEY: text}
        with atomic_path(path) as tmp:
            fig.savefig(tmp, format="png", metadata=metadata, **savefig_kwargs)
    elif path.suffix.lower() == ".svg":
        buffer = io.BytesIO()
        fig.savefig(buffer, format="svg", **savefig_kwargs)
        write_svg(buffer.getvalue(), path, stamp)
    else:
        raise ValueError(f"{path}: write_figure writes .png or .svg files")


def _read_png_stamp(path: Path) -> dict[str, Any] | None:
    # Pillow takes ~50 ms to import; only the readers of PNG stamps pay it.
    from PIL import Image

    try:
        with Image.open(path, formats=["PNG"]) as image:
            text = image.text.get(STAMP_KEY)  # .text also finds chunks after the image data
    except FileNotFoundError:
        raise
    except (OSError, SyntaxError, ValueError) as exc:  # Pillow's errors for a broken file
        raise ValueError(f"{path}: not a readable PNG file ({exc})") from exc
    return None if text is None else _parse_stamp(text, path)


# An element rather than an XML comment: JSON may contain "--", which a comment cannot hold.
_SVG_STAMP_RE = re.compile(
    r'\s*<metadata id="' + re.escape(STAMP_KEY) + r'">[^<]*</metadata>', re.DOTALL
)
# The root start tag; quoted attribute values may contain ">".
_SVG_ROOT_RE = re.compile(r"""<svg\b(?:[^>"']|"[^"]*"|'[^']*')*>""")
_SVG_NS = "{http://www.w3.org/2000/svg}"


def _svg_root(svg: bytes) -> Any:
    """The parsed root element of an SVG document; ValueError when it is not one."""
    try:
        root = ET.fromstring(svg)
    except ET.ParseError as exc:
        raise ValueError(f"not an SVG file (XML parse error: {exc})") from exc
    if root.tag not in ("svg", f"{_SVG_NS}svg"):
        raise ValueError(f"not an SVG file (root element {root.tag!r})")
    return root


def _svg_with_stamp(svg: str | bytes, stamp: Mapping[str, Any]) -> str:
    """``svg`` with ``<metadata id="mjtrial.provenance">`` as the root's first child.

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
    write_text_atomic(path, _svg_with_stamp(svg, stamp))


def _read_svg_stamp(path: Path) -> dict[str, Any] | None:
    try:
        root = _svg_root(path.read_bytes())
    except ValueError as exc:
        raise ValueError(f"{path}: {exc}") from exc
    for element in root:
        if element.tag in ("metadata", f"{_SVG_NS}metadata") and element.get("id") == STAMP_KEY:
            return _parse_stamp(element.text or "", path)
    return None


# --- Logs --------------------------------------------------------------------------------------

_LOG_PREFIX = f"# {STAMP_KEY}: "


def log_stamp_line(stamp: Mapping[str, Any]) -> str:
    """The first line of a job's log: its stamp, so a log says what produced it too."""
    return _LOG_PREFIX + _stamp_json(stamp, ascii_only=True)


def _read_log_stamp(path: Path) -> dict[str, Any] | None:
    with open(path, encoding="utf-8", errors="replace") as f:
        first = f.readline().rstrip("\n")
    return (
        _parse_stamp(first.removeprefix(_LOG_PREFIX), path)
        if first.startswith(_LOG_PREFIX)
        else None
    )


# --- Reading any of them ---------------------------------------------------------------------

_READERS: dict[str, StampReader] = {
    ".parquet": _read_parquet_stamp,
    ".json": _read_json_stamp,
    ".md": _read_markdown_stamp,
    ".png": _read_png_stamp,
    ".svg": _read_svg_stamp,
    ".log": _read_log_stamp,
}

# Formats whose reader lives in a module that imports this one, and registers itself. They are
# imported on the first read (`_load_registered_readers`), not here (they import this module).
_REGISTERED_BY = {".rrd": "mjtrial.recording", "ro-crate-metadata.json": "mjtrial.crate"}

# Folders written as one output other than folders of recordings (which the ".rrd" reader
# reads): (is such a folder, its stamp reader), registered by the modules that write them.
_FOLDER_READERS: list[tuple[Callable[[Path], bool], StampReader]] = []


def register_reader(key: str, reader: StampReader) -> None:
    """Make :func:`read_stamp` read files ending in ``key`` (a suffix such as ``".rrd"``) or
    named ``key`` (a file name such as ``"ro-crate-metadata.json"``, which takes precedence over
    its suffix) with ``reader``.

    ``reader(path)`` returns the stamp, or None when the file carries none, and raises
    ``ValueError`` for a corrupt file. A key registered again gets the new reader.
    """
    if len(key) < 2 or "/" in key or (not key.startswith(".") and "." not in key):
        raise ValueError(f"a file suffix starts with '.', a file name has one; got {key!r}")
    _READERS[key.lower()] = reader


def register_folder_reader(is_folder: Callable[[Path], bool], reader: StampReader) -> None:
    """Make :func:`read_stamp` read a folder for which ``is_folder(folder)`` holds (one output
    made of many files) with ``reader``, and answer for a file inside it that has no stamp of
    its own with that folder's stamp."""
    _FOLDER_READERS.append((is_folder, reader))


def _load_registered_readers() -> None:
    """Import the modules that register readers, so that what `read_stamp` answers never
    depends on what this process happened to import before (the crate's `source/` was "no
    stamp" in a process that had not imported `mjtrial.crate`). By name, not by an import
    statement: a statement would put the readers in the code hash of every stage that stamps
    (`mjtrial.files.codehash`); a stage that reads recordings' stamps imports
    `mjtrial.recording`."""
    for module in dict.fromkeys(_REGISTERED_BY.values()):
        importlib.import_module(module)


def _folder_reader(path: Path) -> StampReader | None:
    for is_folder, reader in _FOLDER_READERS:
        if is_folder(path):
            return reader
    return _READERS.get(".rrd")  # any other folder is read as a folder of recordings


def is_folder_output(path: str | os.PathLike[str]) -> bool:
    """Whether `path` is a folder written as one output: a folder of recordings, or a folder a
    module registered (`register_folder_reader`)."""
    path = Path(path)
    _load_registered_readers()
    return is_recording_folder(path) or any(is_folder(path) for is_folder, _ in _FOLDER_READERS)


def read_output_text(path: str | os.PathLike[str]) -> str:
    """An output's text (a manifest, a seal, a crate), refused in one line if it is a FIFO,
    socket or device (`check_regular`), which would block or never end."""
    check_regular(path, folder=False)
    return Path(path).read_text(encoding="utf-8")


def read_stamp(path: str | os.PathLike[str]) -> dict[str, Any]:
    """Read the stamp embedded in an output file, with the reader registered for its name or
    suffix.

    A folder is read as one output: a folder of ``.rrd`` recordings, or a folder registered with
    :func:`register_folder_reader`. A file with no stamp of its own (no reader for it, or none
    in it) inside such a folder answers with the folder's stamp. Raises
    :class:`MissingStampError` when the file has no stamp, ``ValueError`` for a suffix with no
    reader, a corrupt file/stamp or a FIFO, socket or device (`NotRegularFileError`),
    ``FileNotFoundError`` when it does not exist.
    """
    path = Path(path)
    _load_registered_readers()
    if path.exists():
        check_regular(path)  # a FIFO would block the reader for ever
    if path.is_dir():
        reader = _folder_reader(path)
        suffix = ".rrd"
    else:
        suffix = path.suffix.lower()
        reader = _READERS.get(path.name.lower()) or _READERS.get(suffix)
    stamp = reader(path) if reader is not None else None
    if stamp is None and path.is_file():
        folder = next((p for p in path.parents if is_folder_output(p)), None)
        if folder is not None:
            return read_stamp(folder)
    if reader is None:
        kind = f"{suffix} files" if suffix else "files without a suffix"
        supported = ", ".join(sorted(k for k in _READERS if k.startswith(".")))
        raise ValueError(
            f"{path}: no reader of provenance stamps for {kind} (supported: {supported})"
        )
    if stamp is None:
        raise MissingStampError(f"{path}: no mjtrial provenance stamp")
    return stamp


def content_without_stamp(path: str | os.PathLike[str]) -> bytes | None:
    """An output's content less its stamp, as bytes that are equal exactly when two outputs
    say the same (a stamp holds its creation time, so two builds of one result differ in
    bytes): a table's data and schema, a JSON object without `"provenance"` (canonical), a
    Markdown body, an SVG without its stamp element, a PNG's pixels, a log after its first
    line. None for what has no such form here (recordings, folders)."""
    path = Path(path)
    suffix = path.suffix.lower()
    if path.is_dir():
        return None
    if suffix == ".parquet":
        import pyarrow as pa  # slow imports, see write_parquet
        import pyarrow.parquet as pq

        table = pq.read_table(path).replace_schema_metadata(None)
        sink = pa.BufferOutputStream()
        with pa.ipc.new_stream(sink, table.schema) as writer:
            writer.write_table(table)
        return sink.getvalue().to_pybytes()
    if suffix == ".json":
        obj = json.loads(path.read_text(encoding="utf-8"))
        if isinstance(obj, dict):
            obj.pop("provenance", None)
        return json.dumps(obj, sort_keys=True, separators=(",", ":")).encode()
    if suffix == ".md":
        return _split_front_matter(path.read_text(encoding="utf-8"))[1].encode()
    if suffix == ".svg":
        return _SVG_STAMP_RE.sub("", path.read_text(encoding="utf-8")).encode()
    if suffix == ".png":
        from PIL import Image  # slow import, see _read_png_stamp

        with Image.open(path, formats=["PNG"]) as image:
            return f"{image.mode} {image.size}\n".encode() + image.tobytes()
    if suffix == ".log":
        return b"".join(path.read_bytes().splitlines(keepends=True)[1:])
    return None
