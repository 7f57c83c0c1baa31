"""The docs build with warnings as errors (mkdocs --strict): every page of the user guide and the
API reference, generated from the docstrings of the names a task uses (every name a task or the
new-task template imports from the package), with no broken link."""

from __future__ import annotations

import ast
import subprocess
import sys
from pathlib import Path

import pytest
from conftest import REPO_ROOT

pytestmark = pytest.mark.end_to_end

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
    # every package name a task or the new-task template imports is in the API reference
    pages = " ".join(p.read_text() for p in (tmp_path / "site" / "api").rglob("*.html"))
    imported = _imported_names()
    assert ("mjtrial.sim.physics", "STATE_QPOS") in imported  # the reacher's and cart-pole's
    missing = [f"{m}.{n}" for m, n in sorted(imported) if f'id="{m}.{n}"' not in pages]
    assert missing == []


def _imported_names() -> set[tuple[str, str]]:
    """(module, name) of every `from mjtrial... import name` in tasks/ and the templates."""
    names = set()
    for folder in (REPO_ROOT / "tasks", REPO_ROOT / "src" / "mjtrial" / "templates"):
        for path in folder.rglob("*.py"):
            for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
                if isinstance(node, ast.ImportFrom) and (node.module or "").startswith("mjtrial"):
                    names |= {(node.module, alias.name) for alias in node.names}
    return names


def test_every_recording_path_in_the_guides_is_in_its_shards_folder():
    """A condition's recordings live in `rollouts/<condition>/shard-<i>/` (`Layout`); a path in
    the guides without the shard's folder names no file."""
    import re

    from mjtrial.files.layout import Layout

    shard = Layout.of("research_mode").shard_recordings("fast", "00000").as_posix()
    assert shard.endswith("rollouts/fast/shard-00000")
    wrong = [
        f"{page.name}: {path}"
        for page in (REPO_ROOT / "docs").rglob("*.md")
        for path in re.findall(r"results/[\w./-]*?rollouts/\w+/[\w.*{},-]+\.rrd", page.read_text())
        if not re.search(r"rollouts/\w+/shard-\d{5}/", path)
    ]
    assert wrong == []


def test_verify_help_says_which_config_it_reads(capsys):
    """Without --config, verify reads the config file the results folder's manifest records."""
    import pytest

    from mjtrial.cli import main

    with pytest.raises(SystemExit):
        main(["verify", "--help"])
    text = " ".join(capsys.readouterr().out.split())
    assert "--config CONFIG config file (default: the one the results folder's manifest" in text
    assert "(default: config/config.yaml)" not in text
