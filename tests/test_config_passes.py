"""A config check's pass is remembered per version of what it reads (mjtrial.config.passes):
the same inputs skip the check's simulations; an edit of any of them runs the check again, so
an edit that breaks the experiment is still refused in one line."""

from __future__ import annotations

import shutil
from pathlib import Path

import mujoco
import pytest
import yaml
from conftest import REPO_ROOT, run_snakemake

import mjtrial.config.check as check_module
from mjtrial.config import ConfigError, check_config, passes
from mjtrial.config.passes import CONFIG_CHECKS, check_key, remember_passes

pytestmark = pytest.mark.end_to_end

GANTRY = ("tasks/gantry_lift", "models/gantry_gripper", "config/config.yaml")


def _repo(tmp_path: Path, *parts: str) -> Path:
    """The parts of this checkout a config check reads, copied into `tmp_path`."""
    for part in parts:
        source = REPO_ROOT / part
        if source.is_dir():
            shutil.copytree(source, tmp_path / part, ignore=shutil.ignore_patterns("__pycache__"))
        else:
            (tmp_path / part).parent.mkdir(parents=True, exist_ok=True)
            shutil.copy(source, tmp_path / part)
    return tmp_path


def _config(repo: Path, name: str = "config/config.yaml") -> dict:
    return yaml.safe_load((repo / name).read_text())


@pytest.fixture
def remembered(tmp_path):
    """Passes remembered in a folder of this test's; forgotten after it."""
    folder = tmp_path / "passes"
    remember_passes(folder)
    yield folder
    remember_passes(None)


def _no_simulation(*args, **kwargs):
    raise AssertionError("the check simulated")


def test_a_pass_is_remembered_and_the_same_inputs_skip_the_simulations(
    tmp_path, remembered, monkeypatch
):
    repo = _repo(tmp_path / "repo", *GANTRY)
    config = _config(repo)
    check_config(config, repo_root=repo)
    assert len(list(remembered.iterdir())) == 1
    monkeypatch.setattr(check_module, "run_task_code", _no_simulation)
    check_config(config, repo_root=repo)  # remembered: nothing simulated
    remember_passes(None)  # not remembered: the check runs, and simulates
    with pytest.raises(AssertionError, match="the check simulated"):
        check_config(config, repo_root=repo)


def test_a_broken_task_after_a_pass_is_refused(tmp_path, remembered):
    repo = _repo(tmp_path / "repo", *GANTRY)
    config = _config(repo)
    check_config(config, repo_root=repo)
    task = repo / "tasks" / "gantry_lift" / "task.py"
    task.write_text(task.read_text() + "\nraise RuntimeError('broken on purpose')\n")
    with pytest.raises(ConfigError, match="broken on purpose"):
        check_config(config, repo_root=repo)
    assert len(list(remembered.iterdir())) == 1  # a failed check remembers nothing


def test_a_refused_config_remembers_nothing(tmp_path, remembered):
    repo = _repo(tmp_path / "repo", *GANTRY)
    config = _config(repo)
    config["states"]["n"] = 0
    with pytest.raises(ConfigError, match="states.n"):
        check_config(config, repo_root=repo)
    assert not remembered.exists() or not list(remembered.iterdir())


def _key(repo: Path, config: dict) -> str | None:
    return check_key(
        config,
        repo_root=repo,
        schemas=check_module.SCHEMA_PATH.parent,
        policies=check_module._policy_files(config, repo_root=repo),
    )


def _append(path: Path, text: str) -> None:
    path.write_text(path.read_text() + text)


@pytest.mark.parametrize(
    "edit",
    [
        "a config value",
        "a task file",
        "a new file in the task's folder",
        "a file the model includes",
        "MuJoCo's version",
        "a file of the package",
        "a library's version",
    ],
)
def test_each_input_of_the_check_changes_its_key(tmp_path, monkeypatch, edit):
    repo = _repo(tmp_path / "repo", *GANTRY)
    config = _config(repo)
    before = _key(repo, config)
    assert before is not None and before == _key(repo, _config(repo))
    if edit == "a config value":
        config["states"]["n"] += 1
    elif edit == "a task file":
        _append(repo / "tasks" / "gantry_lift" / "taxonomy.py", "\n# edited\n")
    elif edit == "a new file in the task's folder":
        (repo / "tasks" / "gantry_lift" / "data.csv").write_text("1\n")
    elif edit == "a file the model includes":
        _append(repo / "models" / "gantry_gripper" / "gantry_gripper.xml", "\n<!-- edited -->\n")
    elif edit == "MuJoCo's version":
        monkeypatch.setattr(mujoco, "__version__", "0.0.1")
    elif edit == "a file of the package":
        real = passes._package_files()
        monkeypatch.setattr(passes, "_package_files", lambda: [*real, ["edited.py", "0" * 64]])
    elif edit == "a library's version":
        monkeypatch.setattr(passes, "_version", lambda name: "9.9.9")
    assert _key(repo, config) not in (None, before)


def test_a_policy_file_and_its_contract_change_the_key(tmp_path):
    repo = _repo(
        tmp_path / "repo",
        "tasks/cartpole_latency",
        "policies/cartpole_mlp",
        "config/cartpole_latency.yaml",
    )
    config = _config(repo, "config/cartpole_latency.yaml")
    config["conditions"]["graph"] = {"latency": 0.0, "policy": "policies/cartpole_mlp/seed-1.onnx"}
    paths = check_module._policy_files(config, repo_root=repo)
    assert repo / "policies/cartpole_mlp/seed-1.onnx" in paths
    keys = [_key(repo, config)]
    for path in paths:
        if path.is_file():
            path.write_bytes(path.read_bytes() + b"\n")
            keys.append(_key(repo, config))
    assert len(paths) >= 2 and len(set(keys)) == len(keys) and None not in keys


def test_a_task_named_by_module_has_no_key(tmp_path):
    repo = _repo(tmp_path / "repo", *GANTRY)
    config = _config(repo)
    config["task"] = "some_installed_package.task"
    assert _key(repo, config) is None


def test_snakemake_remembers_a_pass_and_still_refuses_a_broken_task(tmp_path):
    """The workflow's dry run remembers its pass in `CONFIG_CHECKS`; a task file broken after
    it is refused at the next start, in one line."""
    from conftest import copy_workflow

    workdir = copy_workflow(tmp_path)
    run_snakemake(workdir, "-n")
    assert len(list((workdir / CONFIG_CHECKS).iterdir())) == 1
    run_snakemake(workdir, "-n")
    assert len(list((workdir / CONFIG_CHECKS).iterdir())) == 1  # the same key: no new pass
    _append(workdir / "tasks" / "gantry_lift" / "taxonomy.py", "\nraise ValueError('edited')\n")
    proc = run_snakemake(workdir, "-n", check=False)
    assert proc.returncode != 0
    assert "Config error:" in proc.stderr and "edited" in proc.stderr
