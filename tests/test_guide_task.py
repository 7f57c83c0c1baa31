"""The user guide's "Writing a task" example, run as written: the scaffold, the files the page
gives (each fenced block after a `<!-- guide-task: PATH -->` marker), the config keys it
replaces, then the pipeline, the studies and verify, on 24 states instead of 200 for time."""

from __future__ import annotations

import re
from pathlib import Path

import pytest
import yaml
from conftest import REPO_ROOT, copy_workflow, run_snakemake

from mjtrial.cli import main

pytestmark = pytest.mark.end_to_end

CONFIG = "config/pendulum_hold.yaml"
GUIDE = REPO_ROOT / "docs" / "guide" / "task.md"
BLOCK = re.compile(r"<!-- guide-task: (\S+) -->\n```\w*\n(.*?)\n```", re.DOTALL)


def guide_blocks() -> dict[str, str]:
    return dict(BLOCK.findall(GUIDE.read_text(encoding="utf-8")))


def test_the_guide_gives_the_model_the_task_and_the_config():
    assert list(guide_blocks()) == [
        "tasks/pendulum_hold/model.xml",
        "tasks/pendulum_hold/task.py",
        CONFIG,
    ]


@pytest.fixture(scope="module")
def pendulum(tmp_path_factory) -> Path:
    workdir = tmp_path_factory.mktemp("guide_task")
    copy_workflow(workdir)
    assert main(["new-task", "pendulum_hold", "--repo-root", str(workdir)]) == 0
    blocks = guide_blocks()
    for path in ("tasks/pendulum_hold/model.xml", "tasks/pendulum_hold/task.py"):
        (workdir / path).write_text(blocks[path] + "\n")
    config = yaml.safe_load((workdir / CONFIG).read_text())
    config |= yaml.safe_load(blocks[CONFIG])  # "replace these top-level keys"
    config["states"]["n"] = 24
    config["rollout"]["shard_size"] = 12
    config["analysis"]["n_resamples"] = 300
    (workdir / CONFIG).write_text(yaml.safe_dump(config, sort_keys=False))
    run_snakemake(workdir, "--configfile", CONFIG)
    run_snakemake(workdir, "studies", "--configfile", CONFIG)
    return workdir


def test_the_guide_task_runs_its_studies_and_verifies(pendulum):
    from mjtrial.verify import verify_results

    results = pendulum / "results" / "pendulum_hold"
    report = verify_results(
        results, config_path=pendulum / CONFIG, repo_root=pendulum, resimulate=2
    )
    assert report.exit_code == 0, report.format()
    text = (results / "report.md").read_text()
    assert "a pendulum held at an angle" in text
    assert "angle (joint encoder)" in text  # what the policy reads, with its source
    assert (results / "report_dose_response.md").is_file()
    assert "Nothing to be done" in run_snakemake(pendulum, "-n", "--configfile", CONFIG).stdout
