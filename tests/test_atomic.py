"""Tests for mjtrial.files.atomic: outputs appear whole or not at all."""

from __future__ import annotations

import json
import math
import os
from pathlib import Path

import pytest

from mjtrial.files.atomic import (
    atomic_directory,
    atomic_path,
    temp_path_for,
    write_json_atomic,
    write_text_atomic,
)


def _leftovers(directory: Path) -> list[str]:
    return sorted(p.name for p in directory.iterdir() if ".tmp-" in p.name)


def test_content_lands(tmp_path: Path) -> None:
    target = tmp_path / "out.txt"
    with atomic_path(target) as tmp:
        assert tmp.parent == target.parent
        assert not tmp.exists()
        assert not target.exists()  # nothing under the final name while writing
        tmp.write_text("hello\n")
        assert not target.exists()
    assert target.read_text() == "hello\n"
    assert _leftovers(tmp_path) == []


def test_temp_name_hidden_unique_and_keeps_suffix(tmp_path: Path) -> None:
    target = tmp_path / "table.parquet"
    a, b = temp_path_for(target), temp_path_for(target)
    assert a != b
    for t in (a, b):
        assert t.parent == tmp_path
        assert t.name.startswith(".table.parquet.tmp-")
        assert f"-{os.getpid()}-" in t.name
        assert t.suffix == ".parquet"


def test_exception_keeps_old_file_and_no_temp(tmp_path: Path) -> None:
    target = tmp_path / "result.json"
    target.write_bytes(b'{"good": true}\n')
    before = target.read_bytes()
    with pytest.raises(RuntimeError, match="boom"):
        with atomic_path(target) as tmp:
            tmp.write_bytes(b'{"good": fal')  # half-written
            raise RuntimeError("boom")
    assert target.read_bytes() == before
    assert _leftovers(tmp_path) == []


def test_keyboard_interrupt_also_cleans_up(tmp_path: Path) -> None:
    target = tmp_path / "x.txt"
    target.write_text("old")
    with pytest.raises(KeyboardInterrupt):
        with atomic_path(target) as tmp:
            tmp.write_text("partial")
            raise KeyboardInterrupt
    assert target.read_text() == "old"
    assert _leftovers(tmp_path) == []


def test_writer_that_creates_nothing_is_an_error(tmp_path: Path) -> None:
    target = tmp_path / "x.txt"
    target.write_text("old")
    with pytest.raises(FileNotFoundError):
        with atomic_path(target):
            pass
    assert target.read_text() == "old"
    assert _leftovers(tmp_path) == []


def test_parent_dirs_created(tmp_path: Path) -> None:
    target = tmp_path / "a" / "b" / "c" / "out.txt"
    write_text_atomic(target, "x")
    assert target.read_text() == "x"


def test_overwrites_existing(tmp_path: Path) -> None:
    target = tmp_path / "out.txt"
    write_text_atomic(target, "one")
    write_text_atomic(target, "two\r\nlines\n")
    assert target.read_bytes() == b"two\r\nlines\n"  # no newline translation
    assert _leftovers(tmp_path) == []


def test_write_json_atomic_format(tmp_path: Path) -> None:
    target = tmp_path / "o.json"
    obj = {"z": 1, "a": [1.5, "é"], "m": {"k": None}}
    write_json_atomic(target, obj)
    text = target.read_text(encoding="utf-8")
    assert text == json.dumps(obj, indent=2) + "\n"
    assert text.endswith("}\n")
    assert list(json.loads(text)) == ["z", "a", "m"]  # key order kept


def test_write_json_atomic_rejects_nan_without_touching_disk(tmp_path: Path) -> None:
    target = tmp_path / "o.json"
    target.write_text('{"old": 1}\n')
    with pytest.raises(ValueError):
        write_json_atomic(target, {"x": math.nan})
    assert target.read_text() == '{"old": 1}\n'
    assert _leftovers(tmp_path) == []


def test_directory_lands_replaces_the_old_one_whole_and_leaves_no_temp(tmp_path: Path) -> None:
    target = tmp_path / "out" / "fast"
    with atomic_directory(target) as tmp:
        assert tmp.is_dir() and tmp.name.startswith(".fast.tmp-") and not target.exists()
        (tmp / "a.rrd").write_text("old a")
        (tmp / "b.rrd").write_text("old b")
    with atomic_directory(target) as tmp:
        (tmp / "a.rrd").write_text("new a")
    assert sorted(p.name for p in target.iterdir()) == ["a.rrd"]  # b did not survive
    assert (target / "a.rrd").read_text() == "new a"
    assert sorted(p.name for p in target.parent.iterdir()) == ["fast"]


@pytest.mark.parametrize("error", [RuntimeError, KeyboardInterrupt])
def test_directory_failure_keeps_the_old_one_and_no_temp(tmp_path: Path, error) -> None:
    target = tmp_path / "fast"
    with atomic_directory(target) as tmp:
        (tmp / "a.rrd").write_text("good")
    with pytest.raises(error), atomic_directory(target) as tmp:
        (tmp / "a.rrd").write_text("half")
        raise error
    assert [p.name for p in tmp_path.iterdir()] == ["fast"]
    assert (target / "a.rrd").read_text() == "good"


def test_fsync_files_flushes_every_file_once(tmp_path, monkeypatch):
    import threading

    from mjtrial.files import atomic

    paths = [tmp_path / f"f{i}.txt" for i in range(40)]
    for p in paths:
        p.write_text(p.name)
    flushed, lock = [], threading.Lock()

    def record(p):
        with lock:
            flushed.append(Path(p))

    monkeypatch.setattr(atomic, "fsync_file", record)
    atomic.fsync_files(iter(paths))  # a generator, as the crate's copy passes
    assert sorted(flushed) == sorted(paths)
    atomic.fsync_files([])
    assert len(flushed) == 40
