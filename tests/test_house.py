"""The package stays easy to live in: no import cycle, no module over 700 lines, imports inside
functions only with a comment saying why, no path to a file outside the repository."""

from __future__ import annotations

import ast
import re
import subprocess
import sys

import pytest
from conftest import REPO_ROOT

from mjtrial.files import codehash

pytestmark = pytest.mark.end_to_end

PACKAGE = REPO_ROOT / "src" / "mjtrial"
MAX_LINES = 700


def module_name(path) -> str:
    rel = path.relative_to(PACKAGE.parent).with_suffix("")
    parts = rel.parts[:-1] if rel.name == "__init__" else rel.parts
    return ".".join(parts)


MODULES = {module_name(p): p for p in sorted(PACKAGE.rglob("*.py"))}


def find_cycle(graph: dict[str, set[str]]) -> list[str] | None:
    """A cycle of `graph` (a list that starts and ends on the same node), or None."""
    state: dict[str, int] = {}
    stack: list[str] = []

    def visit(node: str) -> list[str] | None:
        state[node] = 1
        stack.append(node)
        for nxt in sorted(graph.get(node, ())):
            if state.get(nxt) == 1:
                return stack[stack.index(nxt) :] + [nxt]
            if nxt not in state and (cycle := visit(nxt)):
                return cycle
        stack.pop()
        state[node] = 2
        return None

    for name in sorted(graph):
        if name not in state and (cycle := visit(name)):
            return cycle
    return None


# The built-in tasks' own words: their elements, parameters and protocol. The package holds
# none of them; a task's words live beside its task file (tasks/<name>/).
TASK_WORDS = re.compile(
    r"\b(cart-pole|cartpole|cart|pole|cubes?|gripper|gantry|carriage|fingers?|pads?|lift_time"
    r"|lifts?|grasp|yaw|latency_20ms)\b",
    re.IGNORECASE,
)


def task_words(text: str) -> list[str]:
    return sorted({m.group(0).lower() for m in TASK_WORDS.finditer(text)})


def test_the_package_names_no_built_in_task():
    found = {
        name: words
        for name, path in MODULES.items()
        if (words := task_words(path.read_text(encoding="utf-8")))
    }
    assert not found, found


def test_task_words_are_found_where_they_are():
    assert task_words("the cube's yaw; a cart-pole") == ["cart-pole", "cube", "yaw"]
    assert task_words("a cartesian polecat, a lifter") == []
    gantry = REPO_ROOT / "tasks" / "gantry_lift"
    assert "cube" in task_words((gantry / "model_spec.py").read_text())


def test_no_import_cycle():
    graph = {
        name: codehash.imported_modules(path.read_text(), module=name) - {name}
        for name, path in MODULES.items()
    }
    assert find_cycle(graph) is None


def test_cycle_search_finds_a_cycle():
    """The search on hand-made sources: a cycle through a module imported inside a function."""
    sources = {
        "mjtrial.stats": "import numpy",
        "mjtrial.verify": (
            "from mjtrial import stats\ndef f():\n    from mjtrial.design import states"
        ),
        "mjtrial.design.states": "from mjtrial.verify import check_stamps",
    }
    graph = {k: codehash.imported_modules(v, module=k) for k, v in sources.items()}
    assert find_cycle(graph) == ["mjtrial.design.states", "mjtrial.verify", "mjtrial.design.states"]
    del sources["mjtrial.design.states"]
    graph = {k: codehash.imported_modules(v, module=k) for k, v in sources.items()}
    assert find_cycle(graph) is None


def test_no_module_over_700_lines():
    long = {n: len(p.read_text().splitlines()) for n, p in MODULES.items()}
    assert {n: c for n, c in long.items() if c > MAX_LINES} == {}


def test_imports_inside_functions_say_why():
    silent = []
    for name, path in MODULES.items():
        lines = path.read_text().splitlines()
        tree = ast.parse("\n".join(lines))
        functions = [n for n in ast.walk(tree) if isinstance(n, ast.FunctionDef)]
        for function in functions:
            for node in ast.walk(function):
                if isinstance(node, ast.Import | ast.ImportFrom):
                    # The comment stands on the line, or above the block of imports it is in.
                    first = node.lineno - 1
                    while lines[first - 1].strip().startswith(("import ", "from ")):
                        first -= 1
                    if "#" not in "".join(lines[first - 1 : node.lineno]):
                        silent.append(f"{name}:{node.lineno}")
    assert silent == []


def test_nothing_refers_to_files_outside_the_repository():
    tracked = subprocess.run(
        ["git", "ls-files"], cwd=REPO_ROOT, capture_output=True, text=True, check=True
    ).stdout.split()
    outside = re.compile(r"DESIGN\.md|\.\./shared")
    hits = [
        f
        for f in tracked
        if not f.endswith((".png", ".rrd"))
        and f != "tests/test_house.py"
        and (REPO_ROOT / f).is_file()
        and outside.search((REPO_ROOT / f).read_text(errors="replace"))
    ]
    assert hits == []


# Benchmarks are `bench_*.py` (a helper they share, such as `alternating.py`, is imported by
# them, so it is checked through them).
SCRIPTS = sorted(
    [
        *REPO_ROOT.glob("benchmarks/bench_*.py"),
        # a model's scripts; its modules (no `__main__`) are checked through them
        *(p for p in REPO_ROOT.glob("models/*/*.py") if "__main__" in p.read_text()),
    ]
)


@pytest.mark.parametrize("script", SCRIPTS, ids=lambda p: str(p.relative_to(REPO_ROOT)))
def test_every_script_beside_the_package_still_imports(script):
    """Scripts no test runs whole (benchmarks, a model's calibration) rot silently when a module
    moves; `--help` imports everything they use and stops before any work."""
    done = subprocess.run(
        [sys.executable, str(script), "--help"], capture_output=True, text=True, timeout=120
    )
    assert done.returncode == 0, done.stderr[-2000:]
    assert "usage:" in done.stdout


def test_the_recording_share_benchmark_runs_the_stage_as_the_pipeline_does(monkeypatch):
    """`--help` imports a benchmark but runs none of its work: the recording share's stage calls
    (states, then each condition's shard with and without its recordings) run here on 3 states,
    so a changed stage contract fails a test, not the next person to measure (a states slice
    without its task did, unseen, for a release)."""
    import yaml

    monkeypatch.syspath_prepend(str(REPO_ROOT / "benchmarks"))
    from bench_vs_plain_loop import logging_share

    from mjtrial.files.layout import CONFIG_FILE

    config = yaml.safe_load((REPO_ROOT / CONFIG_FILE).read_text())
    (share,) = logging_share(config, 3, 1)
    assert -1.0 < share < 1.0  # a CPU share; its size is the benchmark's to measure
