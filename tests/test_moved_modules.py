"""The modules that moved into subpackages (0.4) import by their old names until 0.5: each warns
once, naming its new place, and is the new module itself; nothing in the repository uses an old
name any more."""

from __future__ import annotations

import ast
import importlib
import re
import subprocess
import sys
import warnings
from pathlib import Path

import pytest
from conftest import REPO_ROOT

import mjtrial
from mjtrial._moved import MOVED

pytestmark = pytest.mark.end_to_end

OLD_NAMES = sorted(MOVED)


@pytest.fixture
def forget(monkeypatch):
    """Forget an old name's import (sys.modules and the package attribute) for one test."""

    def forget_name(old: str) -> None:
        parent, _, leaf = old.rpartition(".")
        if leaf in vars(sys.modules[parent]):  # not getattr: `mjtrial.__getattr__` imports
            monkeypatch.delattr(sys.modules[parent], leaf)
        monkeypatch.delitem(sys.modules, old, raising=False)

    return forget_name


def _deprecations(caught: list[warnings.WarningMessage]) -> list[warnings.WarningMessage]:
    return [w for w in caught if issubclass(w.category, DeprecationWarning)]


@pytest.mark.parametrize("old", OLD_NAMES)
def test_an_old_name_imports_the_new_module_and_warns_once(old, forget):
    new = MOVED[old]
    forget(old)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        module = importlib.import_module(old)
        again = importlib.import_module(old)
    assert module is again is importlib.import_module(new) is sys.modules[new]
    assert module.__name__ == new and module.__spec__.name == new
    [warning] = _deprecations(caught)
    assert str(warning.message) == f"{old} moved to {new}; the old name goes in 0.5"
    assert warning.filename == __file__  # the line that imported the old name


def test_from_an_old_name_import_a_name(forget):
    forget("mjtrial.power")
    with pytest.warns(DeprecationWarning, match=r"mjtrial\.power moved to mjtrial\.stats\.power"):
        from mjtrial.power import plan_lines
    from mjtrial.stats.power import plan_lines as new

    assert plan_lines is new


def test_from_the_package_import_an_old_name(forget):
    forget("mjtrial.engine")
    with pytest.warns(DeprecationWarning, match=r"mjtrial\.engine moved to mjtrial\.sim\.engine"):
        from mjtrial import engine
    from mjtrial.sim import engine as new

    assert engine is new
    forget("mjtrial.layout")
    with pytest.warns(DeprecationWarning, match="mjtrial.files.layout"):
        assert mjtrial.layout is importlib.import_module("mjtrial.files.layout")


def test_a_monkeypatch_through_the_old_name_patches_the_one_module(forget, monkeypatch):
    forget("mjtrial.budget")
    with pytest.warns(DeprecationWarning):
        old = importlib.import_module("mjtrial.budget")
    from mjtrial.config import budget

    monkeypatch.setattr(old, "MAX_STEPS_PER_EPISODE", 7)
    assert budget.MAX_STEPS_PER_EPISODE == 7


def test_an_unknown_name_is_still_an_error():
    with pytest.raises(ModuleNotFoundError):
        importlib.import_module("mjtrial.no_such_module")
    with pytest.raises(AttributeError):
        mjtrial.no_such_attribute  # noqa: B018


def test_the_packages_keep_their_names_without_a_warning():
    """`mjtrial.stats` and `mjtrial.config` became packages: every name of the old modules
    imports from them as before, and a fresh interpreter warns of nothing."""
    code = (
        "import warnings\n"
        "warnings.simplefilter('error')\n"
        "from mjtrial.stats import wilson_interval, McNemarResult, MAX_PLANNED_EPISODES\n"
        "from mjtrial.config import check_config, read_config_file, ConfigError, pilot_states\n"
        "from mjtrial.cli import main\n"
        "import mjtrial.stats.paired, mjtrial.config.check\n"
    )
    subprocess.run([sys.executable, "-c", code], check=True, timeout=120)


def test_reading_a_config_does_not_load_the_check():
    """`mjtrial.config.read` (the CLI's) loads neither the config check nor MuJoCo."""
    code = (
        "import sys\n"
        "import mjtrial.config.read\n"
        "print(sorted(m for m in ('mujoco', 'mjtrial.config.check') if m in sys.modules))\n"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "[]"


OLD_DOTTED = re.compile(
    r"\bmjtrial\.(" + "|".join(re.escape(o.split(".", 1)[1]) for o in OLD_NAMES) + r")\b"
)
OLD_LEAVES = {o.split(".", 1)[1] for o in OLD_NAMES}
SCANNED = ("src", "workflow", "benchmarks", "tasks", "policies", "models", "tests")
NOT_SCANNED = {REPO_ROOT / "src" / "mjtrial" / "_moved.py", Path(__file__).resolve()}


def _scanned_files():
    yield REPO_ROOT / "Snakefile"
    for folder in SCANNED:
        for path in sorted((REPO_ROOT / folder).rglob("*")):
            if path.suffix in (".py", ".smk") and "__pycache__" not in path.parts:
                if path.resolve() not in NOT_SCANNED:
                    yield path


def test_nothing_in_the_repository_names_an_old_module():
    found = []
    for path in _scanned_files():
        text = path.read_text(encoding="utf-8")
        rel = path.relative_to(REPO_ROOT)
        found += [f"{rel}: {m.group(0)}" for m in OLD_DOTTED.finditer(text)]
        # `from mjtrial import power`: statements anywhere, in a .py file's syntax tree
        if path.suffix == ".py":
            for node in ast.walk(ast.parse(text)):
                if isinstance(node, ast.ImportFrom) and node.module == "mjtrial":
                    old = [a.name for a in node.names if a.name in OLD_LEAVES]
                    found += [f"{rel}: from mjtrial import {name}" for name in old]
        else:
            for m in re.finditer(r"^\s*from mjtrial import ([^\n(]+)", text, re.MULTILINE):
                names = {n.strip().split(" ")[0] for n in m.group(1).split(",")}
                found += [f"{rel}: from mjtrial import {n}" for n in names & OLD_LEAVES]
    assert found == []
    assert any(p.name == "engine.py" for p in _scanned_files())  # the scan reads the package


def test_no_file_stays_at_an_old_place():
    package = REPO_ROOT / "src" / "mjtrial"
    assert [o for o in OLD_NAMES if (package / f"{o.split('.', 1)[1]}.py").exists()] == []
