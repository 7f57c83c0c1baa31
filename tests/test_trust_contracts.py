"""Which contract a policy file ran with (issue 34 case 8): a `<file>.yaml` added beside a graph
that ran with its folder's `policy.yaml` shadows it; verify names it, whether it changes the
episodes or not, instead of passing the run or calling the honest shard tampered."""

from __future__ import annotations

import shutil
from pathlib import Path

import pytest
import yaml
from conftest import REPO_ROOT, copy_workflow, run_snakemake

from mjtrial.verify import Status, verify_results
from mjtrial.verify.contracts import contract_change

pytestmark = pytest.mark.end_to_end

POLICY = "policies/cartpole_mlp/seed-1.onnx"  # read through the folder's policy.yaml
RESULTS = Path("results") / "mlp_contract"


@pytest.fixture(scope="module")
def built(tmp_path_factory) -> Path:
    """A cart-pole run of 16 states: the task's LQR against a policy file with a folder
    contract."""
    workdir = copy_workflow(tmp_path_factory.mktemp("contract"))
    config = yaml.safe_load((REPO_ROOT / "config" / "cartpole_latency.yaml").read_text())
    config["experiment"] = RESULTS.name
    config["states"].update(n=16)
    config["rollout"]["shard_size"] = 16
    config["analysis"]["n_resamples"] = 300
    config["conditions"] = {"lqr": {"latency": 0.0}, "graph": {"latency": 0.02, "policy": POLICY}}
    config["design"]["falsifier"].update(treatment="lqr", baseline="graph")
    config.pop("sweep", None)
    config.pop("variants", None)
    (workdir / "config" / "config.yaml").write_text(yaml.safe_dump(config, sort_keys=False))
    run_snakemake(workdir)
    return workdir


def verify(workdir: Path):
    return verify_results(
        workdir / RESULTS,
        config_path=workdir / "config" / "config.yaml",
        repo_root=workdir,
        resimulate=16,
    )


@pytest.mark.parametrize("changes_behaviour", [False, True])
def test_a_contract_added_beside_a_policy_file_is_named(built, tmp_path, changes_behaviour):
    work = tmp_path / "experiment"
    shutil.copytree(built, work, symlinks=True)
    assert verify(work).ok
    folder = work / Path(POLICY).parent
    contract = yaml.safe_load((folder / "policy.yaml").read_text())
    if changes_behaviour:  # the observations shifted before the graph: other episodes
        contract["normalization"] = {"mean": [0.05, 0.0], "std": [1.0, 1.0]}
    (folder / "seed-1.yaml").write_text(yaml.safe_dump(contract, sort_keys=False))
    report = verify(work)
    assert not report.ok
    assert report.with_status(Status.TAMPERED) == [], report.format()
    shard = (RESULTS / "rollouts" / "graph" / "shard-00000.parquet").as_posix()
    assert report.status_of(shard) is Status.STALE
    assert report[shard].reasons[0] == (
        f"contract changed: {POLICY} now reads policies/cartpole_mlp/seed-1.yaml, which shadows "
        "policies/cartpole_mlp/policy.yaml it ran with (remove seed-1.yaml or rebuild)"
    )
    lqr = (RESULTS / "rollouts" / "lqr" / "shard-00000.parquet").as_posix()
    assert report.status_of(lqr) is Status.OK


def test_contract_change_names_a_shadowing_and_a_removed_contract(tmp_path):
    """The check both verifies share (an experiment's and a benchmark's): what a graph reads
    now against the contract its stamp records."""
    folder = tmp_path / "policies" / "mlp"
    folder.mkdir(parents=True)
    for name in ("seed-1.onnx", "policy.yaml"):
        (folder / name).write_text(name)
    records = [
        {"path": "policies/mlp/seed-1.onnx", "sha256": "0"},
        {"path": "policies/mlp/policy.yaml", "sha256": "0"},
    ]
    assert contract_change(records, repo_root=tmp_path) is None
    (folder / "seed-1.yaml").write_text("own")
    assert contract_change(records, repo_root=tmp_path) == (
        "contract changed: policies/mlp/seed-1.onnx now reads policies/mlp/seed-1.yaml, which "
        "shadows policies/mlp/policy.yaml it ran with (remove seed-1.yaml or rebuild)"
    )
    own = [records[0], {"path": "policies/mlp/seed-1.yaml", "sha256": "0"}]
    assert contract_change(own, repo_root=tmp_path) is None
    (folder / "seed-1.yaml").unlink()
    assert contract_change(own, repo_root=tmp_path) == (
        "contract changed: policies/mlp/seed-1.onnx now reads policies/mlp/policy.yaml, not "
        "policies/mlp/seed-1.yaml it ran with"
    )
