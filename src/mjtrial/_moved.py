"""The modules that moved into subpackages in 0.4, importable by their old names until 0.5.

`import mjtrial.power` (or `from mjtrial import power`, `from mjtrial.power import x`) warns
once, with a DeprecationWarning naming the new place, and gives the module of the new name
itself, not a copy: `sys.modules` holds one module under both names, so a monkeypatch through
either patches the module the package runs. No file stays at an old place: a finder on
`sys.meta_path` (installed by `mjtrial/__init__.py`) answers for the old names only.
"""

from __future__ import annotations

import importlib
import importlib.abc
import importlib.util
import sys
import warnings
from pathlib import Path
from types import ModuleType

REMOVED_IN = "0.5"

# {old name: new name}
MOVED = {
    "mjtrial.power": "mjtrial.stats.power",
    "mjtrial.sequential": "mjtrial.stats.sequential",
    "mjtrial.comparisons": "mjtrial.stats.comparisons",
    "mjtrial.engine": "mjtrial.sim.engine",
    "mjtrial.closed_loop": "mjtrial.sim.closed_loop",
    "mjtrial.actuation": "mjtrial.sim.actuation",
    "mjtrial.controllers": "mjtrial.sim.controllers",
    "mjtrial.physics": "mjtrial.sim.physics",
    "mjtrial.simenv": "mjtrial.sim.simenv",
    "mjtrial.resimulation": "mjtrial.sim.resimulation",
    "mjtrial.phases": "mjtrial.sim.phases",
    "mjtrial.low_level": "mjtrial.sim.low_level",
    "mjtrial.operational_space": "mjtrial.sim.operational_space",
    "mjtrial.contacts": "mjtrial.sim.contacts",
    "mjtrial.policy_file": "mjtrial.policy_files.file",
    "mjtrial.policy_check": "mjtrial.policy_files.check",
    "mjtrial.onnx_data": "mjtrial.policy_files.onnx_data",
    "mjtrial.config_files": "mjtrial.config.read",
    "mjtrial.config_studies": "mjtrial.config.studies",
    "mjtrial.budget": "mjtrial.config.budget",
    "mjtrial.atomic": "mjtrial.files.atomic",
    "mjtrial.layout": "mjtrial.files.layout",
    "mjtrial.safekeeping": "mjtrial.files.safekeeping",
    "mjtrial.codehash": "mjtrial.files.codehash",
    "mjtrial.conditions": "mjtrial.design.conditions",
    "mjtrial.states": "mjtrial.design.states",
    "mjtrial.registration": "mjtrial.design.registration",
    "mjtrial.task_checks": "mjtrial.task.checks",
    "mjtrial.cli_plan": "mjtrial.cli.plan",
    "mjtrial.scaffold": "mjtrial.cli.scaffold",
}

_IMPORTLIB_DIR = str(Path(importlib.__file__).parent)
# Frames that are not the importing line: this file, and the package's `__getattr__`
# (`mjtrial.power` after `import mjtrial`).
_OURS = (__file__, str(Path(__file__).with_name("__init__.py")))


def _caller_stacklevel() -> int:
    """The `stacklevel` of the first frame outside the import machinery and this package's
    own, so the warning names the line that imported the old name (and is shown where that
    line is). `warnings.warn` itself skips importlib's bootstrap frames when it counts."""
    frame, level = sys._getframe(2), 2  # the frame of the function that calls `warnings.warn`
    while frame is not None:
        file = frame.f_code.co_filename
        internal = "importlib" in file and "_bootstrap" in file  # as `warnings` tells them
        if not internal:
            if not file.startswith(_IMPORTLIB_DIR) and file not in _OURS:
                break
            level += 1
        frame = frame.f_back
    return level


class _MovedLoader(importlib.abc.Loader):
    def __init__(self, new: str) -> None:
        self.new = new

    def create_module(self, spec):  # noqa: ANN001, ANN201 - importlib's signature
        return None  # a placeholder, replaced in sys.modules by exec_module

    def exec_module(self, module: ModuleType) -> None:
        old = module.__name__
        warnings.warn(
            f"{old} moved to {self.new}; the old name goes in {REMOVED_IN}",
            DeprecationWarning,
            stacklevel=_caller_stacklevel(),
        )
        # The import system returns what sys.modules holds under the old name once this
        # returns: the new module itself.
        sys.modules[old] = importlib.import_module(self.new)


class MovedFinder(importlib.abc.MetaPathFinder):
    """Finds the old names of `MOVED`, and nothing else."""

    def find_spec(self, fullname, path=None, target=None):  # noqa: ANN001, ANN201
        new = MOVED.get(fullname)
        if new is None:
            return None
        return importlib.util.spec_from_loader(fullname, _MovedLoader(new))


def install() -> None:
    """Put the finder on `sys.meta_path` once, after the path finders (a real module wins)."""
    if not any(type(f).__name__ == MovedFinder.__name__ for f in sys.meta_path):
        sys.meta_path.append(MovedFinder())


def old_attribute(name: str) -> ModuleType:
    """`mjtrial.<name>` for an old module name not imported yet (`mjtrial.power` after
    `import mjtrial`): the import, with its warning."""
    if f"mjtrial.{name}" not in MOVED:
        raise AttributeError(f"module 'mjtrial' has no attribute {name!r}")
    return importlib.import_module(f"mjtrial.{name}")
