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

REPO_ROOT = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="session")
def gantry_model():
    from mjtrial import model_path
    from mjtrial.simulate import load_model

    return load_model(model_path("gantry_gripper"))


@pytest.fixture(scope="session")
def evaluation_states():
    """The built-in experiment's evaluation states (seed 2026, n = 200)."""
    import yaml

    from mjtrial.states import generate_initial_states, states_from_table

    config = yaml.safe_load((REPO_ROOT / "config" / "config.yaml").read_text())
    s = config["states"]
    return states_from_table(generate_initial_states(seed=s["seed"], n=s["n"], ranges=s["ranges"]))
