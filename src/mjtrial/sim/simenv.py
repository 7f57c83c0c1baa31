"""Another MuJoCo version as a simulator variant: a Python environment of its own, built by uv.

A variant that names a version (`variants.mujoco_4: {mujoco: 4.0.0}`) runs its rollouts in
`envs/mujoco-<version>/venv` of the working folder: this interpreter's Python, every package
of this environment at the version installed here, MuJoCo alone at the named version, and
mjtrial itself installed editable from the checkout that runs (the stages' code hashes then
describe what ran). The environment's lock (`envs/mujoco-<version>/lock.txt`, `uv pip
compile` output with every file's hash) is written last, so its presence means the
environment is whole; the rollouts read it as an input, so their stamps and the crate record
it. uv's cache lies in `envs/uv-cache` (or `UV_CACHE_DIR`): a second build needs no network.
"""

from __future__ import annotations

import hashlib
import importlib.metadata
import json
import os
import re
import subprocess
import sys
from collections.abc import Mapping
from pathlib import Path
from typing import Any

from uv import find_uv_bin

from mjtrial import REPO_ROOT
from mjtrial.design.conditions import sensitivity_conditions, variant_names
from mjtrial.files.atomic import write_text_atomic
from mjtrial.files.layout import NOMINAL, Layout, evaluation_shard_size, shard_ids

ENVS = Path("envs")  # in the working folder (git ignores it)
VERSION_KEY = "mujoco"  # a variant's key naming its MuJoCo version
VERSION_PATTERN = r"^\d+\.\d+\.\d+$"


def variant_version(variant: Mapping[str, Any]) -> str | None:
    """The MuJoCo version a variant's config names, or None."""
    return variant.get(VERSION_KEY)


def model_overrides(variant: Mapping[str, Any]) -> dict[str, Any]:
    """A variant's edits of the model: its config without the MuJoCo version."""
    return {k: v for k, v in variant.items() if k != VERSION_KEY}


def env_folder(version: str) -> Path:
    """The environment's folder for `version`, relative to the working folder."""
    return ENVS / f"mujoco-{version}"


def lock_path(version: str) -> Path:
    return env_folder(version) / "lock.txt"


def env_python(lock: Path | str) -> Path:
    """The environment's interpreter, beside its lock."""
    return Path(lock).parent / "venv" / "bin" / "python"


def requirements(version: str) -> tuple[list[str], list[str]]:
    """mjtrial's own pins with MuJoCo's replaced by `version`, and every other installed
    distribution here at its installed version (constraints: identical pins elsewhere)."""
    pins = [
        r
        for r in importlib.metadata.requires("mjtrial") or []
        if "extra ==" not in r and not r.startswith("mujoco")
    ]
    skip = {"mjtrial", "mujoco"}
    installed = sorted(
        {
            f"{d.metadata['Name']}=={d.version}"
            for d in importlib.metadata.distributions()
            if d.metadata["Name"] and _normal(d.metadata["Name"]) not in skip
        }
    )
    return [f"mujoco=={version}", *pins], installed


def build_key(version: str) -> str:
    """The sha256 of what the environment is built from (the pins, this checkout): a rule's
    param, so that a changed pin here or another checkout builds it again."""
    text = json.dumps([requirements(version), str(REPO_ROOT)])
    return hashlib.sha256(text.encode()).hexdigest()


def _normal(name: str) -> str:
    return re.sub(r"[-_.]+", "-", name).lower()


def uv_environment(workdir: Path) -> dict[str, str]:
    """The process environment uv runs in: its cache in the working folder unless
    `UV_CACHE_DIR` names one, no user or system uv config, no Python downloads."""
    env = dict(os.environ)
    env.setdefault("UV_CACHE_DIR", str(Path(workdir).resolve() / ENVS / "uv-cache"))
    env.update(UV_NO_CONFIG="1", UV_PYTHON_DOWNLOADS="never", UV_NO_PROGRESS="1")
    env.pop("VIRTUAL_ENV", None)
    return env


def build(version: str, lock: Path, *, log: Path) -> None:
    """Build the environment of MuJoCo `version` beside `lock`, then write `lock`.

    Raises `RuntimeError` naming the step and pointing to `log` (uv's own output) when a step
    fails: a version PyPI does not have, no network and no cache.
    """
    folder = Path(lock).parent
    folder.mkdir(parents=True, exist_ok=True)
    venv = folder / "venv"
    wanted, installed = requirements(version)
    (folder / "requirements.in").write_text("\n".join(wanted) + "\n", encoding="utf-8")
    (folder / "constraints.txt").write_text("\n".join(installed) + "\n", encoding="utf-8")
    draft = folder / "lock.txt.draft"
    uv, python = find_uv_bin(), sys.executable
    steps = [
        ("resolve", [uv, "pip", "compile", "--quiet", "--python", python, "--no-header",
                     "--no-annotate", "--generate-hashes", "requirements.in",
                     "--constraints", "constraints.txt", "--output-file", draft.name]),
        ("venv", [uv, "venv", "--quiet", "--allow-existing", "--python", python, "venv"]),
        ("install", [uv, "pip", "sync", "--quiet", "--python", "venv/bin/python",
                     "--require-hashes", draft.name]),
        ("mjtrial", [uv, "pip", "install", "--quiet", "--python", "venv/bin/python",
                     "--no-deps", "--editable", str(REPO_ROOT)]),
    ]  # fmt: skip
    env = uv_environment(Path.cwd())
    with open(log, "a", encoding="utf-8") as out:
        for step, command in steps:
            out.write(f"$ {' '.join(map(str, command))}\n")
            out.flush()
            done = subprocess.run(command, cwd=folder, env=env, stdout=out, stderr=out)
            if done.returncode != 0:
                raise RuntimeError(
                    f"MuJoCo {version}'s environment: `uv {command[1]} {command[2]}` ({step}) "
                    f"failed; uv's output is in {log}"
                )
    check_env(venv / "bin" / "python", version)
    write_text_atomic(lock, draft.read_text(encoding="utf-8"))
    draft.unlink()


def check_env(python: Path, version: str) -> None:
    """Raise `RuntimeError` unless `python` imports MuJoCo `version` and this mjtrial."""
    probe = "import mujoco, mjtrial; print(mujoco.__version__); print(mjtrial.__file__)"
    out = subprocess.run([str(python), "-c", probe], capture_output=True, text=True)
    found = out.stdout.split()
    own = Path(sys.modules["mjtrial"].__file__).resolve()
    if out.returncode != 0 or found[:1] != [version] or Path(found[1]).resolve() != own:
        raise RuntimeError(
            f"{python}: expected MuJoCo {version} and mjtrial from {own.parent}, found "
            f"{' '.join(found) or out.stderr.strip()[-200:]}"
        )


def run_in_env(snakemake: Any) -> None:
    """Re-execute this job's script under its variant's environment, when the job has one
    (an input `simulator_env`, the environment's lock) and does not run there yet.

    Call before anything imports MuJoCo: the script starts again in the environment's Python,
    with the same `snakemake` object (the script file Snakemake wrote, `sys.argv[0]`)."""
    lock = snakemake.input.get("simulator_env")
    if not lock:
        return
    python = env_python(lock).absolute()
    if Path(sys.prefix).resolve() == python.parent.parent.resolve():
        return
    sys.stdout.flush()
    sys.stderr.flush()
    os.execv(python, [str(python), sys.argv[0]])


def version_recordings(
    config: Mapping[str, Any], layout: Layout
) -> dict[str, dict[str, list[Path]]]:
    """The shard folders of recordings a sensitivity study reads, per variant (`NOMINAL`
    first) and condition: every condition the study reads under the nominal model and under each
    variant that names another MuJoCo version, whose flipped episodes' trajectories are
    compared; none when there is no such variant or nothing is recorded."""
    versions = [v for v in variant_names(config) if variant_version(config["variants"][v])]
    if not versions or config["recording"]["episodes"] == "none":
        return {}
    shards = shard_ids(config["states"]["n"], evaluation_shard_size(config))
    return {
        v: {
            c: [layout.shard_recordings(c, s, v) for s in shards]
            for c in sensitivity_conditions(config)
        }
        for v in [NOMINAL, *versions]
    }
