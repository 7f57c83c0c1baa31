"""A FIFO (or any file that is not a regular file) where mjtrial hashes or reads an output is
refused in one line, never read: reading a FIFO blocks until something writes to it."""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

pytestmark = pytest.mark.end_to_end

MJTRIAL = str(Path(sys.executable).parent / "mjtrial")
RESULTS = "results/research_mode"
TIMEOUT = 60  # s: far more than any of these takes; a command that blocks fails, not hangs


def _run(*args: str, cwd: Path) -> subprocess.CompletedProcess:
    return subprocess.run(args, cwd=cwd, capture_output=True, text=True, timeout=TIMEOUT)


def _fifo(path: Path) -> None:
    if path.exists():
        path.unlink()
    os.mkfifo(path)


def test_provenance_of_a_fifo_is_one_line(tmp_path):
    _fifo(tmp_path / "summary.json")
    proc = _run(MJTRIAL, "provenance", "summary.json", cwd=tmp_path)
    assert proc.returncode == 1
    assert proc.stderr.strip().splitlines() == [
        "mjtrial provenance: summary.json: a FIFO; expected a regular file or a folder"
    ]


@pytest.mark.parametrize("inside", [False, True])
def test_hashing_a_fifo_or_a_folder_holding_one_is_refused(tmp_path, inside):
    folder = tmp_path / "recordings"
    folder.mkdir()
    (folder / "a.rrd").write_bytes(b"a")
    target = folder / "b.rrd"
    _fifo(target)
    hashed = folder if inside else target
    code = f"from mjtrial import provenance; provenance.file_sha256({str(hashed)!r})"
    proc = _run(sys.executable, "-c", code, cwd=tmp_path)
    assert proc.returncode == 1
    assert f"NotRegularFileError: {target}: a FIFO; expected a regular file" in proc.stderr


def test_verify_names_a_fifo_among_the_outputs(built, tmp_path):
    workdir = tmp_path / "copy"
    shutil.copytree(built, workdir)
    results = workdir / RESULTS
    _fifo(results / "analysis" / "summary.json")
    _fifo(results / "manifest.json")
    proc = _run(MJTRIAL, "verify", RESULTS, "--resimulate", "0", cwd=workdir)
    assert proc.returncode == 1, proc.stderr
    for name in ("analysis/summary.json", "manifest.json"):
        assert f"{RESULTS}/{name}: no readable stamp (NotRegularFileError: a FIFO" in proc.stdout
    # A FIFO inside a folder output (a shard's recordings): the folder's hash is refused.
    (results / "manifest.json").unlink()
    shutil.copy(built / RESULTS / "manifest.json", results / "manifest.json")
    _fifo(results / "rollouts" / "fast" / "shard-00000" / "zz.rrd")
    proc = _run(MJTRIAL, "verify", RESULTS, "--resimulate", "0", cwd=workdir)
    assert proc.returncode == 2
    assert proc.stderr.strip().endswith("shard-00000/zz.rrd: a FIFO; expected a regular file")
