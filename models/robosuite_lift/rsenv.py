"""robosuite 1.5.2's own Python environment, for the scripts beside this file.

robosuite 1.5.2 builds Lift on MuJoCo up to 3.9.0 (3.10.0 changed `mj_fullM`'s arguments, which
robosuite's controller calls; 3.14.0 also fails earlier, in robosuite's joint-type check). So
the scripts here run in an environment of their own: `envs/robosuite-1.5.2/venv` of the working
folder (git ignores `envs/`), built by uv from `requirements.txt` beside this file (every
package pinned with its hashes: `uv pip compile --generate-hashes requirements.in`). A script
calls `ensure()` first: under any other interpreter it builds the environment once (uv's cache in
`envs/uv-cache` unless `UV_CACHE_DIR` names one) and starts again under its Python.

`ROBOSUITE_MUJOCO=3.14.0` selects instead robosuite 1.5.2 on MuJoCo 3.14.0
(`requirements-mujoco-3.14.0.txt`, `envs/robosuite-1.5.2-mujoco-3.14.0/`), with the three
shims of `mujoco_compat.py` applied: the same MuJoCo as mjtrial's own environment.
"""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
from pathlib import Path

HERE = Path(__file__).resolve().parent
REQUIREMENTS = HERE / "requirements.txt"
ROBOSUITE = "1.5.2"
MUJOCO = os.environ.get("ROBOSUITE_MUJOCO", "3.9.0")
if MUJOCO == "3.9.0":
    REQUIREMENTS, VENV = REQUIREMENTS, Path("envs") / f"robosuite-{ROBOSUITE}" / "venv"
elif MUJOCO == "3.14.0":
    REQUIREMENTS = HERE / "requirements-mujoco-3.14.0.txt"
    VENV = Path("envs") / f"robosuite-{ROBOSUITE}-mujoco-3.14.0" / "venv"
else:
    sys.exit(f"rsenv: ROBOSUITE_MUJOCO is {MUJOCO!r}; expected 3.9.0 (default) or 3.14.0")


def _versions_here() -> tuple[str, str] | None:
    try:
        import mujoco
        import robosuite
    except ImportError:
        return None
    return robosuite.__version__, mujoco.__version__


def _uv() -> str:
    try:
        from uv import find_uv_bin

        return find_uv_bin()
    except ImportError:
        found = shutil.which("uv")
        if found is None:
            sys.exit("rsenv: uv is needed to build robosuite's environment (pip install uv)")
        return found


def ensure() -> None:
    """Return when this interpreter has robosuite 1.5.2 and MuJoCo 3.9.0; else build the
    environment (once) and re-run this script under its Python."""
    if _versions_here() == (ROBOSUITE, MUJOCO):
        if MUJOCO != "3.9.0":
            import mujoco_compat

            mujoco_compat.apply()
        return
    python = VENV.absolute() / "bin" / "python"
    if Path(sys.prefix).resolve() == python.parent.parent.resolve():
        sys.exit(f"rsenv: {python} lacks robosuite {ROBOSUITE} with MuJoCo {MUJOCO}")
    if not python.exists():
        env = dict(os.environ, UV_NO_CONFIG="1", UV_PYTHON_DOWNLOADS="never")
        env.setdefault("UV_CACHE_DIR", str(Path("envs/uv-cache").absolute()))
        env.pop("VIRTUAL_ENV", None)
        uv = _uv()
        for command in (
            [uv, "venv", "--quiet", "--python", sys.executable, str(VENV)],
            [uv, "pip", "sync", "--quiet", "--python", str(python), "--require-hashes",
             str(REQUIREMENTS)],
        ):  # fmt: skip
            print("rsenv:", " ".join(command), file=sys.stderr)
            subprocess.run(command, env=env, check=True)
    sys.stdout.flush()
    sys.stderr.flush()
    os.execv(python, [str(python), *sys.argv])
