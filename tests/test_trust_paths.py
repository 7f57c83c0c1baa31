"""Files outside the repository (issue 34 case 9 and the symlinks of case 14): a policy path
through `../<checkout>/`, a `--configfile` outside the repository, a contract or a benchmark's
policy file symlinked outside it. Each is refused in one line naming the key or the file: the
run records paths relative to the repository and its crate, `source/` and zip hold the
repository's files only, so the zip of such a run would not verify elsewhere."""

from __future__ import annotations

import shutil
from pathlib import Path

import pytest
import yaml
from conftest import REPO_ROOT, copy_workflow, error_lines, run_snakemake

from mjtrial.benchmark.config import check_benchmark_config
from mjtrial.config import ConfigError, check_config, read_config_file

pytestmark = pytest.mark.end_to_end

FOLDER = "policies/cartpole_mlp"


@pytest.fixture
def repo(tmp_path) -> Path:
    """The config, models, tasks and policies in a checkout named `checkout`."""
    root = tmp_path / "checkout"
    for name in ("config", "models", "tasks", "policies"):
        shutil.copytree(REPO_ROOT / name, root / name)
    return root


def _policy_config(policy: str) -> dict:
    config = yaml.safe_load((REPO_ROOT / "config" / "cartpole_latency.yaml").read_text())
    config["conditions"] = {"lqr": {"latency": 0.0}, "graph": {"latency": 0.02, "policy": policy}}
    config["design"]["falsifier"].update(treatment="lqr", baseline="graph")
    config.pop("sweep", None)
    config.pop("variants", None)
    return config


def _refused(config: dict, repo: Path) -> str:
    with pytest.raises(ConfigError) as err:
        check_config(config, source="config/x.yaml", repo_root=repo)
    assert "\n" not in str(err.value)
    return str(err.value)


def test_a_policy_path_through_the_checkouts_folder_is_refused(repo):
    check_config(_policy_config(f"{FOLDER}/seed-1.onnx"), source="config/x.yaml", repo_root=repo)
    assert _refused(_policy_config(f"../checkout/{FOLDER}/seed-1.onnx"), repo) == (
        "config/x.yaml: conditions.graph.policy: expected a path relative to the repository "
        "without '..' (policies/<name>/<file>.onnx), got "
        "'../checkout/policies/cartpole_mlp/seed-1.onnx'"
    )


def test_a_contract_symlinked_outside_the_repository_is_refused_as_a_graph_is(repo, tmp_path):
    outside = tmp_path / "outside"
    outside.mkdir()
    contract = repo / FOLDER / "policy.yaml"
    shutil.move(contract, outside / "policy.yaml")
    contract.symlink_to(outside / "policy.yaml")
    assert _refused(_policy_config(f"{FOLDER}/seed-1.onnx"), repo) == (
        "config/x.yaml: conditions.graph.policy: policies/cartpole_mlp/policy.yaml: a symlink to "
        "a file outside the repository; expected a file inside it"
    )
    graph = repo / FOLDER / "seed-2.onnx"  # refused before this change too
    shutil.move(graph, outside / "seed-2.onnx")
    graph.symlink_to(outside / "seed-2.onnx")
    assert "seed-2.onnx: a symlink to a file outside the repository" in _refused(
        _policy_config(f"{FOLDER}/seed-2.onnx"), repo
    )


@pytest.mark.parametrize("name", ["policy.yaml", "seed-3.onnx"])
def test_a_benchmark_policy_file_symlinked_outside_the_repository_is_refused(repo, tmp_path, name):
    source = "config/benchmark.yaml"
    shipped = read_config_file(REPO_ROOT / source)
    check_benchmark_config(shipped, source=source, repo_root=repo)
    outside = tmp_path / "outside"
    outside.mkdir()
    shutil.move(repo / FOLDER / name, outside / name)
    (repo / FOLDER / name).symlink_to(outside / name)
    with pytest.raises(ConfigError) as err:
        check_benchmark_config(shipped, source=source, repo_root=repo)
    assert str(err.value) == (
        f"{source}: benchmark.methods.mlp_es.tasks.cartpole_latency.policy: {FOLDER}/{name}: a "
        "symlink to a file outside the repository; expected a file inside it"
    )


def test_a_configfile_outside_the_repository_is_refused_in_one_line(tmp_path):
    (tmp_path / "checkout").mkdir()
    workdir = copy_workflow(tmp_path / "checkout")
    outside = tmp_path / "small.yaml"
    outside.write_text(yaml.safe_dump({"states": {"n": 12}}))
    proc = run_snakemake(workdir, "-n", "--configfile", "../small.yaml", check=False)
    assert proc.returncode != 0
    assert error_lines(proc) == [
        "Config error: --configfile ../small.yaml: outside the repository; expected a config "
        "file inside it (say, config/), so that the run's source/, crate and zip hold it"
    ]
    # the same file inside the repository runs
    shutil.copy(outside, workdir / "config" / "small.yaml")
    run_snakemake(workdir, "-n", "--configfile", "config/small.yaml")
