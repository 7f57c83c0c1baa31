"""The fourth hostile survey, the regression gate: `mjtrial diff --fail-on any` compares what is
on disk, not what the seals say. Each test failed before its fix."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import pyarrow as pa
import pyarrow.parquet as pq
import pytest

from mjtrial.cli import main
from mjtrial.files.layout import Layout

pytestmark = pytest.mark.end_to_end

LAYOUT = Layout.of("research_mode")


def flip_row(path: Path, state_id: int) -> None:
    """Flip one episode's success in a rollout table, keeping its stamp (schema metadata)."""
    table = pq.read_table(path)
    success = table.column("success").to_pylist()
    row = table.column("state_id").to_pylist().index(state_id)
    success[row] = not success[row]
    i = table.column_names.index("success")
    table = table.set_column(i, table.schema.field(i), pa.array(success, type=pa.bool_()))
    pq.write_table(table, path)


def _diff(capsys, *args) -> tuple[int, str, str]:
    code = main(["diff", *map(str, args)])
    out = capsys.readouterr()
    return code, out.out, out.err


def test_a_tampered_copy_fails_the_gate_and_says_which_files(built, tmp_path, capsys):
    """Survey case 1: a copy with one success flipped in its table and shard and the verdict
    edited in summary.json said "0 differ" and passed `--fail-on any`."""
    a = built / LAYOUT.root
    b = tmp_path / "copy"
    shutil.copytree(a, b, symlinks=True)
    shard = b / LAYOUT.shard_table("fast", "00000").relative_to(LAYOUT.root)
    flip_row(shard, 2)
    flip_row(b / LAYOUT.rollout_table("fast").relative_to(LAYOUT.root), 2)
    summary_path = b / LAYOUT.summary.relative_to(LAYOUT.root)
    summary = json.loads(summary_path.read_text())
    summary["falsifier"]["verdict"] = (
        "refuted" if summary["falsifier"]["verdict"] != "refuted" else "survives"
    )
    summary_path.write_text(json.dumps(summary))
    code, out, err = _diff(capsys, a, b, "--fail-on", "any", "--out", tmp_path / "d")
    assert code == 1, out + err
    line = next(x for x in err.splitlines() if "no longer match their seal" in x)
    for rel in ("analysis/summary.json", "rollouts/fast.parquet", "rollouts/fast/shard-00000"):
        assert rel in line, line
    assert "in b" in line and "3 NOT AS SEALED" in out, out
    # The other gates refuse a run whose files are not what it sealed, too.
    code, _, err = _diff(capsys, a, b, "--fail-on", "changed", "--out", tmp_path / "d")
    assert code == 1 and "no longer match their seal" in err, err


def test_a_deleted_recordings_folder_fails_the_gate(built, tmp_path, capsys):
    """Survey case 1: with b's recordings folder deleted, "28 the same", exit 0."""
    a = built / LAYOUT.root
    b = tmp_path / "copy"
    shutil.copytree(a, b, symlinks=True)
    folder = LAYOUT.shard_recordings("slow", "00001").relative_to(LAYOUT.root)
    shutil.rmtree(b / folder)
    code, out, err = _diff(capsys, a, b, "--fail-on", "any", "--out", tmp_path / "d")
    assert code == 1, out + err
    assert f"sealed outputs missing in b: {folder.as_posix()}" in err, err
    assert f"missing in b: {folder.as_posix()}" in out
    # The untouched copy of the same run passes.
    shutil.rmtree(b)
    shutil.copytree(a, b, symlinks=True)
    code, out, err = _diff(capsys, a, b, "--fail-on", "any", "--out", tmp_path / "d")
    assert code == 0, err
    assert "0 differ" in out
