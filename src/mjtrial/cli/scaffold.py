"""`mjtrial new-task NAME`: a task folder and a config that run end to end as generated.

The templates (`mjtrial/templates/new_task/`) are a working experiment named `new_task`: a
block pushed along a rail to a line, open loop. The scaffold copies them with the name
replaced, so what a researcher starts from is a task that already runs, verifies and reports,
with comments marking what to change.
"""

from __future__ import annotations

import re
from pathlib import Path

TEMPLATE = Path(__file__).resolve().parents[1] / "templates" / "new_task"
PLACEHOLDER = "new_task"
# A Python identifier in lower case: it names a folder, a module-like task and results/<name>.
NAME = re.compile(r"[a-z][a-z0-9_]*\Z")
# Template file -> where it goes, relative to the repository.
FILES = {
    "task.py": "tasks/{name}/task.py",
    "model.xml": "tasks/{name}/model.xml",
    "config.yaml": "config/{name}.yaml",
}


class ScaffoldError(ValueError):
    """A name the scaffold refuses, or files it would overwrite."""


def new_task(name: str, *, repo_root: Path) -> list[Path]:
    """Write the task folder and its config under `repo_root`; returns the paths written.

    Raises:
      ScaffoldError: the name is not a lower-case identifier, or a file it would write exists.
    """
    if not NAME.match(name):
        raise ScaffoldError(
            f"new-task: {name!r}: expected a lower-case name of letters, digits and _, "
            "starting with a letter (it names tasks/<name>/ and config/<name>.yaml)"
        )
    targets = {src: Path(repo_root) / dst.format(name=name) for src, dst in FILES.items()}
    existing = [str(p) for p in targets.values() if p.exists()]
    if existing:
        raise ScaffoldError(f"new-task: {', '.join(existing)}: exists; nothing written")
    for src, dst in targets.items():
        dst.parent.mkdir(parents=True, exist_ok=True)
        text = (TEMPLATE / src).read_text(encoding="utf-8")
        dst.write_text(text.replace(PLACEHOLDER, name), encoding="utf-8")
    return list(targets.values())
