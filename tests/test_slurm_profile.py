"""The SLURM profile's job groups (`profiles/slurm/config.yaml`, `groups`) against the workflow's
DAG, without SLURM: Snakemake checks a group when it builds the DAG, whatever the executor, and
refuses one that a rule outside it both feeds and reads from. A rule added after the rollouts
and left out of the group stops every SLURM run before its first job (it did: the figures job),
which only the SLURM round trip (`tests/cluster`, root and Debian's packages) would show."""

from __future__ import annotations

import pytest
import yaml
from conftest import REPO_ROOT, copy_workflow, run_snakemake

pytestmark = pytest.mark.end_to_end


def profile_groups() -> list[str]:
    profile = yaml.safe_load((REPO_ROOT / "profiles" / "slurm" / "config.yaml").read_text())
    return list(profile["groups"])


@pytest.mark.parametrize(
    "configfile", [None, "config/benchmark.yaml"], ids=["experiment", "benchmark"]
)
def test_the_profile_groups_fit_the_dag(tmp_path, configfile):
    workdir = copy_workflow(tmp_path)
    args = ["-n", "--groups", *profile_groups()]
    if configfile:
        args += ["--configfile", configfile]
    proc = run_snakemake(workdir, *args, check=False)
    assert proc.returncode == 0, proc.stderr[-2000:]
    assert "downstream" in proc.stdout  # the group's jobs are planned as one
