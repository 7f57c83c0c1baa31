"""mjtrial: research-mode MuJoCo experiments, designed before they run and stamped after."""

from __future__ import annotations

from pathlib import Path
from types import ModuleType

from mjtrial import _moved

__version__ = "0.1.0"

# The models, config and workflow ship inside the repository (not the wheel): an editable
# install finds them here.
REPO_ROOT = Path(__file__).resolve().parents[2]
MODELS_DIR = REPO_ROOT / "models"

# The modules that moved into subpackages answer to their old names until 0.5, with a warning
# (mjtrial._moved).
_moved.install()


def __getattr__(name: str) -> ModuleType:
    return _moved.old_attribute(name)


def foreign_package(checkout: Path) -> str | None:
    """Why the imported `mjtrial` is not the checkout's own `src/mjtrial`, or None.

    Another checkout's editable install would run, hash and stamp its own code under this
    checkout's commit; a folder without `src/mjtrial` (a copy of the workflow only) runs the
    installed package, which the stamps then record.
    """
    own = Path(checkout).resolve() / "src" / "mjtrial"
    here = Path(__file__).resolve().parent
    if own.is_dir() and here != own.resolve():
        return (
            f"the imported mjtrial is {here}, not this checkout's {own}; expected this "
            "checkout's own package (pip install -e . here, or PYTHONPATH=src)"
        )
    return None


def model_path(name: str) -> Path:
    """Path of a model's scene file by name, floor and light included.

    ``model_path("gantry_gripper")`` is the file to pass to ``mujoco.MjModel.from_xml_path``.
    """
    path = MODELS_DIR / name / "scene.xml"
    if not path.is_file():
        known = sorted(p.name for p in MODELS_DIR.iterdir() if (p / "scene.xml").is_file())
        raise FileNotFoundError(f"model {name!r}: no {path}; known models: {known}")
    return path
