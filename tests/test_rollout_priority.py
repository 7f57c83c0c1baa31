"""The rollout jobs' Snakemake priority (rule rollout, `rollout_priority`): a shard's physics
steps in thousands, its states times its condition's episode steps, so that the scheduler
starts the longest shards first and the short ones fill the cores at the end. Read from
Snakemake's own dry run (what its scheduler will use) and checked against the episodes' lengths
worked out from each protocol's published timings, not from the code under test."""

from __future__ import annotations

import re

import mujoco
import pytest
import yaml
from conftest import REPO_ROOT, copy_workflow, run_snakemake

pytestmark = pytest.mark.end_to_end

JOB = re.compile(
    r"rule rollout:\n(?:    .*\n)*?    wildcards: condition=(\w+), shard=(\d+)\n"
    r"    priority: (\d+)\n"
)


def dry_run_priorities(workdir, *args: str) -> dict[tuple[str, int], int]:
    """(condition, shard) -> the priority Snakemake's dry run gives the rollout job."""
    out = run_snakemake(workdir, "-n", *args).stdout
    return {(c, int(s)): int(p) for c, s, p in JOB.findall(out)}


def edit(path, n: int, shard_size: int) -> None:
    config = yaml.safe_load(path.read_text())
    config["states"]["n"] = n
    config["rollout"]["shard_size"] = shard_size
    path.write_text(yaml.safe_dump(config, sort_keys=False))


def test_the_slow_lifts_shards_come_first_and_a_short_last_shard_last(tmp_path):
    workdir = copy_workflow(tmp_path)
    edit(workdir / "config" / "config.yaml", n=2500, shard_size=1000)
    timestep = mujoco.MjModel.from_xml_path(
        str(REPO_ROOT / "models" / "gantry_gripper" / "scene.xml")
    ).opt.timestep
    # tasks/gantry_lift/protocol.py: settle 0.3 s, 100 descent set-points of 10 ms, pre-close
    # 0.3 s, close 0.6 s, the lift, hold 0.5 s; each hold round(duration / timestep) steps
    episode = {
        name: round((0.3 + 100 * 0.01 + 0.3 + 0.6 + lift + 0.5) / timestep)
        for name, lift in (("fast", 0.15), ("slow", 1.5))
    }
    assert episode == {"fast": 1425, "slow": 2100}  # at the model's 2 ms
    expected = {
        (c, shard): states * episode[c] // 1000
        for c in episode
        for shard, states in ((0, 1000), (1, 1000), (2, 500))
    }
    got = dry_run_priorities(workdir)
    assert got == expected
    # the slow lift's full shards before any fast one; the short last shards last
    assert sorted(got, key=got.get)[:2] == [("fast", 2), ("slow", 2)]


def test_a_foreign_robots_shards_have_the_suites_episode_length(tmp_path):
    # gymnasium-robotics' Fetch: 50 actions an episode (max_episode_steps), 20 physics steps
    # each (n_substeps): 1,000 steps, whatever the condition
    workdir = copy_workflow(tmp_path)
    edit(workdir / "config" / "fetch_pick.yaml", n=3000, shard_size=2000)
    got = dry_run_priorities(workdir, "--configfile", "config/fetch_pick.yaml")
    assert got == {
        (c, shard): states * 50 * 20 // 1000
        for c in ("noise_25mm", "noise_40mm")
        for shard, states in ((0, 2000), (1, 1000))
    }
