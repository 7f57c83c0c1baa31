"""Several rerun streams in one valid .rrd file, through ``rerun rrd route``.

``failures.rrd`` and a replay's file hold several streams (recordings, and a blueprint). Each
is encoded with ``ChunkStore.write_rrd`` (or a blueprint's ``save``) into the stdin of
``rerun rrd route`` (the CLI in the rerun-sdk wheel), which writes them as one stream with one
valid footer. Plain concatenation is not enough: rerun 0.41's reader and ``rerun rrd verify``
reject concatenated files, and files without a footer. (A blueprint sent into a recording's
stream can make ``route`` panic, so the blueprint travels as a stream of its own.) The CLI
runs with ``CI`` set, the only environment switch of rerun 0.41 that stops it from writing
analytics files under the home folder. (rerun 0.41's ``route`` panics when given its own
output as input: combine these files with ``rerun rrd merge`` instead.)
"""

from __future__ import annotations

import functools
import importlib.util
import os
import shutil
import subprocess
import sys
import tempfile
from collections.abc import Callable, Iterable, Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import IO

import rerun.blueprint as rrb
from rerun.chunk import Chunk, ChunkStore

from mjtrial.recording.arrow import strict


def rerun_cli() -> str:
    """The rerun CLI binary shipped in the rerun-sdk wheel (package `rerun_cli`)."""
    spec = importlib.util.find_spec("rerun_cli")
    if spec is not None and spec.submodule_search_locations:
        exe = "rerun.exe" if sys.platform.startswith("win") else "rerun"
        candidate = Path(next(iter(spec.submodule_search_locations))) / exe
        if candidate.is_file():
            return str(candidate)
    found = shutil.which("rerun")
    if found is None:
        raise RuntimeError("the rerun CLI was not found (it ships with rerun-sdk as rerun_cli)")
    return found


def _cli_env() -> dict[str, str]:
    """Environment for the rerun CLI: with `CI` set, rerun 0.41 writes no analytics files."""
    return {**os.environ, "CI": os.environ.get("CI", "1")}


# Niceness added to `rerun rrd route`, a process of its own: at a lower priority than whatever
# else runs, it takes the gaps they leave.
_ROUTE_NICENESS = 10


def _lower_priority(pid: int, niceness: int) -> None:
    """Best effort: raise the niceness of a process."""
    if niceness <= 0:
        return
    try:
        os.setpriority(os.PRIO_PROCESS, pid, os.getpriority(os.PRIO_PROCESS, pid) + niceness)
    except (AttributeError, OSError):  # no setpriority (Windows), or not permitted: run as is
        pass


def _fd_path(fd: int) -> str | None:
    """A path that opens file descriptor `fd` again (Linux, macOS, BSDs), or None."""
    for directory in ("/proc/self/fd", "/dev/fd"):
        if os.path.isdir(directory):
            return f"{directory}/{fd}"
    return None


class RrdFileWriter:
    """Writes rerun streams, one after another, as one valid .rrd file.

    Feeds them to ``rerun rrd route -o <path>``, which re-frames them as a single stream with one
    footer. Each stream is written by a rerun writer given a path (`write_rrd`, a blueprint's
    `save`): the path of route's stdin where the OS has one, so the stream goes straight into the
    pipe, else a scratch file whose bytes are then copied. Writing blocks while route catches up
    (its stdout goes to /dev/null and its stderr to a file, so route never waits for us).
    """

    def __init__(self, path: Path, scratch: Path) -> None:
        self._stderr: IO[bytes] = tempfile.TemporaryFile()
        self._proc = subprocess.Popen(
            [rerun_cli(), "rrd", "route", "-o", str(path)],
            stdin=subprocess.PIPE,
            stdout=subprocess.DEVNULL,
            stderr=self._stderr,
            env=_cli_env(),
        )
        _lower_priority(self._proc.pid, _ROUTE_NICENESS)
        assert self._proc.stdin is not None
        self._stdin = self._proc.stdin
        self._direct = _fd_path(self._stdin.fileno())
        self._part = scratch / "stream.rrd"

    def write(self, writer: Callable[[str], None], *, direct: bool = True) -> None:
        """Append the stream that `writer(path)` writes to `path`.

        `direct` False goes through the scratch file even where route's stdin has a path: for
        writers that do not return when the pipe breaks (a blueprint's `save` writes from a
        thread of its own).
        """
        try:
            if direct and self._direct is not None:
                writer(self._direct)
            else:
                writer(str(self._part))
                try:
                    self._stdin.write(self._part.read_bytes())
                    self._stdin.flush()  # before any direct write
                finally:
                    self._part.unlink()
        except Exception as exc:
            if self._proc.poll() is None:
                raise
            # route exited early: the broken pipe is only the symptom
            raise RuntimeError(f"rerun rrd route stopped early: {self._error_text()}") from exc

    def close(self) -> None:
        try:
            try:
                self._stdin.close()
            except OSError:
                pass  # route's exit code and stderr say why
            code = self._proc.wait()
            if code != 0:
                raise RuntimeError(f"rerun rrd route failed (exit {code}): {self._error_text()}")
        finally:
            self._stderr.close()

    def abort(self) -> None:
        self._proc.kill()
        self._proc.wait()
        try:
            self._stdin.close()
        except OSError:
            pass
        self._stderr.close()

    def _error_text(self) -> str:
        self._stderr.seek(0)
        text = self._stderr.read().decode("utf-8", "replace").strip()
        return text[-2000:] or "no output"


@contextmanager
def rrd_output(
    path: Path, application_id: str, blueprint: rrb.Blueprint
) -> Iterator[RrdFileWriter]:
    """The writer of `path`'s stream, which starts with `blueprint`."""
    with tempfile.TemporaryDirectory(dir=path.parent, prefix=f".{path.name}.parts-") as scratch:
        writer = RrdFileWriter(path, Path(scratch))
        try:
            writer.write(functools.partial(save_blueprint, blueprint, application_id), direct=False)
            yield writer
        except BaseException:
            writer.abort()
            raise
        writer.close()


def save_blueprint(blueprint: rrb.Blueprint, application_id: str, path: str) -> None:
    """A blueprint as a stream of its own (an .rbl file), active and default."""
    try:
        blueprint.save(application_id, path)
    except RuntimeError as exc:  # e.g. "Blueprint stream has no store info"
        raise RuntimeError(
            f"rerun could not encode the blueprint ({exc}); is rerun disabled (RERUN=off)?"
        ) from exc


def write_store(
    out: RrdFileWriter, store: ChunkStore, *, application_id: str, recording_id: str
) -> None:
    """Append one recording, the chunks of `store`, to `out`.

    Writing a `ChunkStore` needs no GIL, whereas a stream over Python objects takes it for every
    chunk: in a worker thread it would wait for the caller's thread, which holds the GIL while it
    prepares the next rollout.
    """

    def writer(path: str) -> None:
        with strict():
            store.write_rrd(path, application_id=application_id, recording_id=recording_id)

    out.write(writer)


def write_recording(
    out: RrdFileWriter, chunks: Iterable[Chunk], *, application_id: str, recording_id: str
) -> None:
    """Append one recording of `chunks` to `out`."""
    with strict():
        store = ChunkStore.from_chunks(list(chunks))
    write_store(out, store, application_id=application_id, recording_id=recording_id)
