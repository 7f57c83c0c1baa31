"""Tests for mjtrial.provenance.formats: a stamp in every output format, and read_stamp."""

from __future__ import annotations

import io
import json
import re
import struct
import xml.etree.ElementTree as ET
import zlib
from pathlib import Path

import matplotlib
import pyarrow as pa
import pyarrow.parquet as pq
import pytest
from matplotlib.figure import Figure

from mjtrial.provenance import (
    MissingStampError,
    formats,
    read_stamp,
    register_folder_reader,
    register_reader,
    write_figure,
    write_json,
    write_markdown,
    write_parquet,
    write_svg,
)

pytestmark = pytest.mark.end_to_end

# A stamp as make_stamp builds them, with text that JSON, XML and PNG must each carry intact:
# non-ASCII (beyond Latin-1 too), "--" (no XML comment can hold it), and <, &, >.
STAMP = {
    "mjtrial_stamp": 1,
    "rule": "report",
    "config_slice": {"episodes": 3, "noise": [0.1, 0.2]},
    "extra": {"note": "ünïcode ✓", "cmd": "plan --x <a & b>"},
}


def _no_temp_files(folder: Path) -> bool:
    return not [p for p in folder.iterdir() if ".tmp-" in p.name]


def _png_chunk(ctype: bytes, data: bytes) -> bytes:
    return struct.pack(">I", len(data)) + ctype + data + struct.pack(">I", zlib.crc32(ctype + data))


def _tiny_png(*extra_chunks: bytes) -> bytes:
    """A valid 1x1 8-bit greyscale PNG built by hand, `extra_chunks` just before IEND."""
    ihdr = struct.pack(">IIBBBBB", 1, 1, 8, 0, 0, 0, 0)
    return (
        b"\x89PNG\r\n\x1a\n"
        + _png_chunk(b"IHDR", ihdr)
        + _png_chunk(b"IDAT", zlib.compress(b"\x00\x7f"))
        + b"".join(extra_chunks)
        + _png_chunk(b"IEND", b"")
    )


def _parse_png(data: bytes) -> list[tuple[bytes, bytes]]:
    """Independent PNG chunk parser that checks every CRC and that IEND ends the file."""
    assert data[:8] == b"\x89PNG\r\n\x1a\n"
    pos, chunks = 8, []
    while pos < len(data):
        (length,) = struct.unpack(">I", data[pos : pos + 4])
        ctype = data[pos + 4 : pos + 8]
        body = data[pos + 8 : pos + 8 + length]
        (crc,) = struct.unpack(">I", data[pos + 8 + length : pos + 12 + length])
        assert len(body) == length
        assert zlib.crc32(ctype + body) == crc, f"bad CRC in {ctype!r}"
        chunks.append((ctype, body))
        pos += 12 + length
    assert pos == len(data)
    assert chunks[0][0] == b"IHDR"
    assert chunks[-1] == (b"IEND", b"")
    return chunks


def _text_chunks(data: bytes) -> dict[bytes, tuple[bytes, bytes]]:
    """keyword -> (chunk type, raw text) of a PNG's text chunks."""
    out = {}
    for ctype, body in _parse_png(data):
        if ctype in (b"tEXt", b"zTXt", b"iTXt"):
            keyword, _, value = body.partition(b"\0")
            assert keyword not in out, f"two text chunks named {keyword!r}"
            out[keyword] = (ctype, value)
    return out


def _figure() -> Figure:
    fig = Figure(figsize=(2, 1.5))
    ax = fig.add_subplot()
    ax.plot([0, 1, 2], [0.0, 0.4, 0.3], label="height")
    ax.set_title("cube ü")
    return fig


# --------------------------------------------------------------------------------------------
# Parquet, JSON, Markdown
# --------------------------------------------------------------------------------------------


def test_parquet_roundtrip(tmp_path: Path) -> None:
    table = pa.table({"a": [1, 2, 3], "b": ["x", "y", "z"]}).replace_schema_metadata(
        {b"other": b"keep me"}
    )
    path = tmp_path / "out" / "table.parquet"
    write_parquet(table, path, STAMP)
    assert table.schema.metadata == {b"other": b"keep me"}  # input not modified
    assert read_stamp(path) == STAMP

    back = pq.read_table(path)
    assert back.equals(table)  # data unchanged
    assert back.schema.metadata[b"other"] == b"keep me"
    assert json.loads(back.schema.metadata[b"mjtrial.provenance"]) == STAMP
    assert _no_temp_files(path.parent)


def test_json_roundtrip(tmp_path: Path) -> None:
    obj = {"metric": 0.5, "provenance": "stale", "rows": [1, 2]}
    path = tmp_path / "summary.json"
    write_json(obj, path, STAMP)
    assert obj["provenance"] == "stale"  # caller's object untouched
    assert read_stamp(path) == STAMP
    data = json.loads(path.read_text(encoding="utf-8"))
    assert data == {"metric": 0.5, "rows": [1, 2], "provenance": STAMP}
    assert path.read_text(encoding="utf-8").endswith("}\n")


def test_markdown_roundtrip(tmp_path: Path) -> None:
    body = "# Report\n\nSome text.\n\n---\n\nafter a rule\n"
    path = tmp_path / "report.md"
    write_markdown(body, path, STAMP)
    text = path.read_text(encoding="utf-8")
    lines = text.split("\n")
    assert lines[0] == "---"
    assert lines[1].startswith("provenance: {")
    assert lines[2] == "---"
    assert text == "\n".join(lines[:3]) + "\n" + body
    assert json.loads(lines[1][len("provenance: ") :]) == STAMP
    assert read_stamp(path) == STAMP

    yaml = pytest.importorskip("yaml")
    assert yaml.safe_load("\n".join(lines[1:2]))["provenance"] == STAMP


def test_markdown_merges_existing_front_matter(tmp_path: Path) -> None:
    path = tmp_path / "r.md"
    write_markdown("---\ntitle: Hello\nprovenance: {}\n---\nbody\n", path, STAMP)
    text = path.read_text(encoding="utf-8")
    assert text.count("provenance:") == 1
    assert "title: Hello\n---\nbody\n" in text
    assert read_stamp(path) == STAMP


# --------------------------------------------------------------------------------------------
# Figures: PNG
# --------------------------------------------------------------------------------------------


def test_figure_png_carries_the_stamp_as_an_ascii_text_chunk(tmp_path: Path) -> None:
    fig = _figure()
    path = tmp_path / "fig" / "plot.png"
    write_figure(fig, path, STAMP, dpi=50, metadata={"Software": None, "Title": "heights"})
    data = path.read_bytes()
    texts = _text_chunks(data)
    ctype, raw = texts[b"mjtrial.provenance"]
    assert ctype == b"tEXt" and raw.isascii()  # Latin-1 by the PNG spec: ASCII survives as is
    assert json.loads(raw) == STAMP
    assert texts[b"Title"] == (b"tEXt", b"heights")  # the caller's metadata kept
    assert b"Software" not in texts
    assert read_stamp(path) == STAMP
    assert _no_temp_files(path.parent)

    # The image is matplotlib's own: the same chunks as an unstamped save, plus the stamp.
    plain = io.BytesIO()
    fig.savefig(plain, format="png", dpi=50, metadata={"Software": None, "Title": "heights"})
    stamped_chunks = [c for c in _parse_png(data) if not c[1].startswith(b"mjtrial.provenance")]
    assert stamped_chunks == _parse_png(plain.getvalue())


def test_figure_png_long_stamp_roundtrip(tmp_path: Path) -> None:
    # ~300 kB of JSON, far above any single-chunk limit a reader might have for text.
    stamp = {**STAMP, "config_slice": {f"key {i} ✓": "ẞ" * 50 + str(i) for i in range(2000)}}
    path = tmp_path / "long.png"
    write_figure(_figure(), path, stamp, dpi=20)
    assert read_stamp(path) == stamp


def test_png_stamped_after_the_image_data_reads(tmp_path: Path) -> None:
    # Figures stamped before matplotlib wrote the stamp: a tEXt chunk just before IEND.
    text = json.dumps(STAMP, ensure_ascii=True).encode("ascii")
    path = tmp_path / "old.png"
    path.write_bytes(_tiny_png(_png_chunk(b"tEXt", b"mjtrial.provenance\0" + text)))
    assert read_stamp(path) == STAMP


def test_corrupt_png_is_an_error_not_a_missing_stamp(tmp_path: Path) -> None:
    bad_crc = bytearray(_tiny_png())
    bad_crc[20] ^= 0xFF  # inside IHDR data
    write_figure(_figure(), tmp_path / "whole.png", STAMP, dpi=50)
    whole = (tmp_path / "whole.png").read_bytes()
    for name, data in [
        ("signature.png", b"not a png at all"),
        ("crc.png", bytes(bad_crc)),
        ("truncated.png", whole[: len(whole) // 2]),  # the stamp intact, half the image lost
    ]:
        (tmp_path / name).write_bytes(data)
        with pytest.raises(ValueError, match="not a readable PNG") as info:
            read_stamp(tmp_path / name)
        assert not isinstance(info.value, MissingStampError)


# --------------------------------------------------------------------------------------------
# Figures: SVG
# --------------------------------------------------------------------------------------------

_SVG = (
    '<?xml version="1.0" encoding="utf-8" standalone="no"?>\n'
    '<!DOCTYPE svg PUBLIC "-//W3C//DTD SVG 1.1//EN"\n'
    '  "http://www.w3.org/Graphics/SVG/1.1/DTD/svg11.dtd">\n'
    '<svg xmlns="http://www.w3.org/2000/svg" width="10pt" height="10pt" data-x="a>b">\n'
    " <metadata><title>other metadata</title></metadata>\n"
    ' <rect width="5" height="5"/>\n'
    "</svg>\n"
)
# The stamp element as the test reads it: one line, first child of the root.
_STAMP_ELEMENT = re.compile(r'\n <metadata id="mjtrial\.provenance">[^<]*</metadata>')


def test_svg_roundtrip_and_restamp(tmp_path: Path) -> None:
    path = tmp_path / "fig" / "plot.svg"
    write_svg(_SVG.encode("utf-8"), path, STAMP)
    stamped = path.read_text(encoding="utf-8")
    root = ET.fromstring(stamped.encode("utf-8"))
    assert root[0].tag == "{http://www.w3.org/2000/svg}metadata"
    assert root[0].get("id") == "mjtrial.provenance"
    assert json.loads(root[0].text) == STAMP
    assert _STAMP_ELEMENT.sub("", stamped) == _SVG  # the rest of the document untouched
    assert read_stamp(path) == STAMP

    write_svg(stamped, path, {**STAMP, "rule": "other"})
    again = path.read_text(encoding="utf-8")
    assert again.count("mjtrial.provenance") == 1
    assert read_stamp(path)["rule"] == "other"


def test_figure_svg_is_matplotlibs_document_with_the_stamp(tmp_path: Path) -> None:
    fig = _figure()
    kwargs = {"metadata": {"Date": None, "Creator": None}}
    with matplotlib.rc_context({"svg.hashsalt": "fixed"}):  # else element ids are random
        plain = io.BytesIO()
        fig.savefig(plain, format="svg", **kwargs)
        path = tmp_path / "plot.svg"
        write_figure(fig, path, STAMP, **kwargs)
    assert _STAMP_ELEMENT.sub("", path.read_text(encoding="utf-8")) == plain.getvalue().decode()
    assert read_stamp(path) == STAMP


def test_svg_bad_input(tmp_path: Path) -> None:
    (tmp_path / "broken.svg").write_text("<svg><g></svg>", encoding="utf-8")
    with pytest.raises(ValueError, match="not an SVG"):
        read_stamp(tmp_path / "broken.svg")
    with pytest.raises(ValueError, match="not an SVG"):
        write_svg("<html></html>", tmp_path / "html.svg", STAMP)
    with pytest.raises(ValueError, match="not an SVG"):
        write_svg("not xml", tmp_path / "text.svg", STAMP)
    assert list(tmp_path.iterdir()) == [tmp_path / "broken.svg"]


# --------------------------------------------------------------------------------------------
# Every format
# --------------------------------------------------------------------------------------------


def test_missing_stamp_every_format(tmp_path: Path) -> None:
    pq.write_table(pa.table({"a": [1]}), tmp_path / "plain.parquet")
    (tmp_path / "plain.json").write_text('{"a": 1}\n')
    (tmp_path / "list.json").write_text("[1, 2]\n")
    (tmp_path / "plain.md").write_text("# Title\n")
    (tmp_path / "front.md").write_text("---\ntitle: x\n---\n# Title\n")
    (tmp_path / "plain.png").write_bytes(_tiny_png())
    (tmp_path / "plain.svg").write_text(_SVG, encoding="utf-8")
    names = ["plain.parquet", "plain.json", "list.json", "plain.md", "front.md", "plain.png"]
    for name in [*names, "plain.svg"]:
        path = tmp_path / name
        with pytest.raises(MissingStampError) as info:
            read_stamp(path)
        assert isinstance(info.value, ValueError)
        assert str(info.value) == f"{path}: no mjtrial provenance stamp"


def test_writers_reject_non_stamps(tmp_path: Path) -> None:
    not_a_stamp = {"rule": "report"}
    writers = {
        "a.json": lambda p: write_json({"a": 1}, p, not_a_stamp),
        "a.md": lambda p: write_markdown("# x\n", p, not_a_stamp),
        "a.parquet": lambda p: write_parquet(pa.table({"a": [1]}), p, not_a_stamp),
        "a.svg": lambda p: write_svg(_SVG, p, not_a_stamp),
        "b.png": lambda p: write_figure(_figure(), p, not_a_stamp),
    }
    for name, write in writers.items():
        with pytest.raises(ValueError, match="mjtrial_stamp"):
            write(tmp_path / name)
    assert list(tmp_path.iterdir()) == []


def test_write_figure_needs_png_or_svg(tmp_path: Path) -> None:
    with pytest.raises(ValueError, match=r"\.png or \.svg"):
        write_figure(_figure(), tmp_path / "plot.pdf", STAMP)
    assert list(tmp_path.iterdir()) == []


# --------------------------------------------------------------------------------------------
# The registry of readers
# --------------------------------------------------------------------------------------------


@pytest.fixture
def readers(monkeypatch: pytest.MonkeyPatch) -> dict:
    """The built-in readers only (no .rrd), restored after the test."""
    builtin = {k: v for k, v in formats._READERS.items() if k != ".rrd"}
    monkeypatch.setattr(formats, "_READERS", builtin)
    return builtin


def test_registered_reader_is_used_by_suffix(readers: dict, tmp_path: Path) -> None:
    seen = []

    def reader(path: Path) -> dict | None:
        seen.append(path)
        return None if path.stem == "bare" else {**STAMP, "from": path.name}

    register_reader(".XYZ", reader)  # suffixes match whatever their case
    (tmp_path / "run.xyz").write_bytes(b"")
    assert read_stamp(str(tmp_path / "run.xyz")) == {**STAMP, "from": "run.xyz"}
    with pytest.raises(MissingStampError, match="no mjtrial provenance stamp"):
        read_stamp(tmp_path / "bare.Xyz")
    assert seen == [tmp_path / "run.xyz", tmp_path / "bare.Xyz"]


def test_a_folder_is_read_as_rrd_recordings(readers: dict, tmp_path: Path) -> None:
    folder = tmp_path / "fast"
    folder.mkdir()
    register_reader(".rrd", lambda path: {**STAMP, "from": path.name})
    assert read_stamp(folder) == {**STAMP, "from": "fast"}


def test_a_file_without_a_stamp_in_a_folder_output_answers_with_the_folders(
    readers: dict, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """A shard's blueprint.rbl and Snakemake's timestamp answer with the shard's stamp; the
    files of a registered folder (nested, or Markdown without front matter) with its own."""
    monkeypatch.setattr(formats, "_FOLDER_READERS", [])
    register_reader(".rrd", lambda path: {**STAMP, "from": path.name} if path.is_dir() else None)
    shard = tmp_path / "shard-00000"
    shard.mkdir()
    (shard / "blueprint.rbl").write_bytes(b"layout")
    (shard / ".snakemake_timestamp").write_bytes(b"")
    assert read_stamp(shard / "blueprint.rbl") == {**STAMP, "from": "shard-00000"}
    assert read_stamp(shard / ".snakemake_timestamp") == {**STAMP, "from": "shard-00000"}
    (tmp_path / "loose.rbl").write_bytes(b"")  # in no folder output: no reader for it
    with pytest.raises(ValueError, match=r"no reader of provenance stamps for \.rbl files"):
        read_stamp(tmp_path / "loose.rbl")
    with pytest.raises(FileNotFoundError):  # a missing file is not its folder's
        read_stamp(shard / "absent.json")

    register_folder_reader(lambda p: p.name == "copy", lambda p: {**STAMP, "from": "copy"})
    nested = tmp_path / "copy" / "src"
    nested.mkdir(parents=True)
    (nested / "a.py").write_text("x = 1\n")
    (tmp_path / "copy" / "README.md").write_text("# no front matter\n")
    assert read_stamp(nested / "a.py") == {**STAMP, "from": "copy"}
    assert read_stamp(tmp_path / "copy" / "README.md") == {**STAMP, "from": "copy"}
    assert read_stamp(tmp_path / "copy") == {**STAMP, "from": "copy"}
    assert formats.is_folder_output(tmp_path / "copy") and formats.is_folder_output(shard)
    assert not formats.is_folder_output(nested)


def test_a_reader_registered_by_name_comes_before_the_suffixs(
    readers: dict, tmp_path: Path
) -> None:
    register_reader("ro-crate-metadata.json", lambda path: {**STAMP, "from": "by name"})
    (tmp_path / "ro-crate-metadata.json").write_text("{}")
    (tmp_path / "other.json").write_text("{}")
    assert read_stamp(tmp_path / "ro-crate-metadata.json") == {**STAMP, "from": "by name"}
    with pytest.raises(MissingStampError):
        read_stamp(tmp_path / "other.json")
    with pytest.raises(ValueError, match="a file name has one"):
        register_reader("Snakefile", lambda path: None)


def test_unregistered_suffixes_are_clear_errors(readers: dict, tmp_path: Path) -> None:
    (tmp_path / "x.csv").write_text("a\n")
    with pytest.raises(ValueError, match=r"\.csv files \(supported: \.json, \.log, \.md"):
        read_stamp(tmp_path / "x.csv")
    with pytest.raises(FileNotFoundError):
        read_stamp(tmp_path / "absent.json")
    with pytest.raises(ValueError, match="starts with '.'"):
        register_reader("rrd", lambda path: None)


def test_a_fresh_process_reads_every_output_having_imported_only_provenance(built) -> None:
    """The readers of recordings and of the crate's `source/` live in modules that register
    them; a process that imported none of them (a user's script, one test alone) read the
    sources' folder as "no mjtrial provenance stamp" and a recording as unreadable."""
    import subprocess
    import sys

    results = built / "results" / "research_mode"
    paths = [
        results / "source",
        results / "source" / "Snakefile",
        results / "replay" / "failures.rrd",
    ]
    script = (
        "import sys\n"
        "from mjtrial.provenance import read_stamp\n"
        "for path in sys.argv[1:]:\n"
        "    print(read_stamp(path)['rule'])\n"
    )
    proc = subprocess.run(
        [sys.executable, "-c", script, *map(str, paths)], capture_output=True, text=True
    )
    assert proc.returncode == 0, proc.stderr
    assert proc.stdout.split() == ["crate", "crate", "failures"]
