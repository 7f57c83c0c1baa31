"""Shared fixtures. Tests never write to the home folder: HOME and the XDG folders point at a
temporary directory for the whole session (rerun writes analytics settings there)."""

from __future__ import annotations

import os
import tempfile
from pathlib import Path

import pytest

_HOME = Path(tempfile.mkdtemp(prefix="mjtrial-test-home-"))
os.environ.update(
    HOME=str(_HOME),
    XDG_CONFIG_HOME=str(_HOME / ".config"),
    XDG_DATA_HOME=str(_HOME / ".local" / "share"),
    XDG_CACHE_HOME=str(_HOME / ".cache"),
    RERUN_ANALYTICS="0",
    MPLBACKEND="Agg",
)
# Where the environment forbids bytecode files, every job process compiles the package's modules
# from source again (a rollout job's import of them: 0.17 s against 0.07 s from bytecode): the
# suite's processes keep their bytecode, as a user's Python does.
os.environ.pop("PYTHONDONTWRITEBYTECODE", None)

REPO_ROOT = Path(__file__).resolve().parents[1]


def pytest_addoption(parser: pytest.Parser) -> None:
    parser.addoption(
        "--time-breakdown",
        action="store_true",
        help="print where the suite's time went: Snakemake runs, verify, other processes, "
        "copying, the tests' own work (tests/time_breakdown.py)",
    )


# `pytest -m "not end_to_end"`: the tests that build no experiment, a few minutes in all. A file
# whose tests run Snakemake, verify a run or run another process for seconds says so with
# `pytestmark = pytest.mark.end_to_end`; a test that runs Snakemake, or reads the session's
# `built`, outside such a file fails at once, so the quick selection never quietly grows.
END_TO_END = "end_to_end"
_current = {"end_to_end": True}  # True outside a test (the benchmarks import this module)


@pytest.hookimpl(tryfirst=True)
def pytest_runtest_setup(item: pytest.Item) -> None:
    _current["end_to_end"] = item.get_closest_marker(END_TO_END) is not None
    if "built" in item.fixturenames:
        _require_end_to_end(f"{item.nodeid} reads the session's built experiment")


def _require_end_to_end(what: str) -> None:
    if not _current["end_to_end"]:
        raise AssertionError(
            f"{what}: mark its file `pytestmark = pytest.mark.{END_TO_END}` (tests/conftest.py)"
        )


def pytest_configure(config: pytest.Config) -> None:
    config.addinivalue_line(
        "markers",
        f"{END_TO_END}: builds or verifies an experiment, or runs another process for seconds "
        '(`pytest -m "not end_to_end"` leaves these out)',
    )
    if config.getoption("time_breakdown"):
        from time_breakdown import TimeBreakdown

        # pytest_configure is historic: pytest calls the plugin's on registration
        config.pluginmanager.register(TimeBreakdown(), "time_breakdown")


@pytest.fixture(scope="session")
def gantry_model():
    from mjtrial import model_path
    from mjtrial.sim.physics import load_model

    return load_model(model_path("gantry_gripper"))


@pytest.fixture(scope="session")
def evaluation_states():
    """The built-in experiment's evaluation states (seed 2026, n = 200)."""
    import yaml
    from gantry_lift.states import STATE_PARAMETERS, states_from_table

    from mjtrial.design.states import generate_initial_states

    config = yaml.safe_load((REPO_ROOT / "config" / "config.yaml").read_text())
    s = config["states"]
    return states_from_table(
        generate_initial_states(
            seed=s["seed"], n=s["n"], ranges=s["ranges"], parameters=STATE_PARAMETERS
        )
    )


SNAKEMAKE = str(Path(__import__("sys").executable).parent / "snakemake")
WORKFLOW_FILES = ("Snakefile", "workflow", "config", "models", "tasks", "profiles", "policies")


# Large model folders no test writes into: linked into a test's copy of the workflow, not
# copied (robosuite's Lift is 45 MB of meshes; the pipeline tests copy the workflow about a
# hundred times).
LINKED = ("models/robosuite_lift",)


def copy_workflow(workdir: Path) -> Path:
    """The workflow's files (`WORKFLOW_FILES`) copied into `workdir`, a folder to run it in
    (the `LINKED` folders as symbolic links)."""
    import shutil

    def ignore(folder: str, names: list[str]) -> list[str]:
        return [n for n in names if (Path(folder) / n).relative_to(REPO_ROOT).as_posix() in LINKED]

    for name in WORKFLOW_FILES:
        src = REPO_ROOT / name
        if src.is_dir():
            shutil.copytree(src, workdir / name, ignore=ignore)
        else:
            shutil.copy(src, workdir / name)
    for rel in LINKED:
        (workdir / rel).symlink_to(REPO_ROOT / rel, target_is_directory=True)
    return workdir


def edit_config(workdir: Path, edit) -> None:
    """Apply `edit` to the workdir's config/config.yaml."""
    import yaml

    path = workdir / "config" / "config.yaml"
    config = yaml.safe_load(path.read_text())
    edit(config)
    path.write_text(yaml.safe_dump(config, sort_keys=False))


def run_snakemake(workdir: Path, *args: str, check: bool = True, env: dict | None = None):
    """Run Snakemake in `workdir`; `env` adds environment variables (e.g. PYTHONPATH).

    Forked from a process that has Snakemake imported (`forked_snakemake`), unless `env` sets
    PYTHONPATH: another copy of the package needs a fresh process."""
    import subprocess

    import forked_snakemake

    _require_end_to_end(f"snakemake {' '.join(args)} in {workdir}")
    argv = ["-c2", *args]
    environment = os.environ | (env or {})
    if "PYTHONPATH" in (env or {}):
        proc = subprocess.run(
            [SNAKEMAKE, *argv],
            cwd=workdir,
            capture_output=True,
            text=True,
            timeout=600,
            env=environment,
        )
    else:
        proc = forked_snakemake.run(SNAKEMAKE, argv, workdir, dict(environment), timeout=600)
    if check and proc.returncode != 0:
        raise AssertionError(f"snakemake {args} failed:\n{proc.stdout}\n{proc.stderr}")
    return proc


def error_lines(proc) -> list[str]:
    """What a failed Snakemake run printed on stderr, less its note on the profile it used."""
    return [
        line
        for line in proc.stderr.splitlines()
        if line.strip() and not line.startswith("Using workflow specific profile")
    ]


@pytest.fixture(scope="session")
def built(tmp_path_factory) -> Path:
    """A small copy of the experiment built once by Snakemake: 12 states in shards of 5 (two
    full shards and a partial one), 500 resamples."""
    import shutil

    workdir = tmp_path_factory.mktemp("experiment")
    for name in WORKFLOW_FILES:
        src = REPO_ROOT / name
        (shutil.copytree if src.is_dir() else shutil.copy)(src, workdir / name)

    def small(config):
        config["states"]["n"] = 12
        config["rollout"]["shard_size"] = 5
        config["analysis"]["n_resamples"] = 500

    edit_config(workdir, small)
    run_snakemake(workdir)
    return workdir
