"""The docs build with warnings as errors (mkdocs --strict): every page of the user guide and the
API reference, generated from the docstrings of the names a task uses, with no broken link."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

from conftest import REPO_ROOT

MKDOCS = str(Path(sys.executable).parent / "mkdocs")


def test_the_docs_build_strict(tmp_path):
    build = subprocess.run(
        [MKDOCS, "build", "--strict", "--site-dir", str(tmp_path / "site")],
        cwd=REPO_ROOT,
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert build.returncode == 0, build.stderr
    api = (tmp_path / "site" / "api" / "task" / "index.html").read_text()
    for name in ("StateParameter", "Custom", "Observation", "ClosedLoop", "Series"):
        assert f'id="mjtrial.task.{name}"' in api, name
    assert 'id="mjtrial.closest_calls.Margin"' in api

