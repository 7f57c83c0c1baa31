"""Stopping early in the pipeline (config `stopping`): a look after every `look_every` states
(a shard), a checkpoint; a stopped experiment's later shards never run, the summary, manifest
and report hold the stop, and `mjtrial verify` recomputes it. The guide's example, on the
shipped config, stops early. Without the section the plan is the one it always was."""

from __future__ import annotations

import json
import math
import re
from pathlib import Path

import pyarrow.parquet as pq
import pytest
import yaml
from conftest import REPO_ROOT, copy_workflow, edit_config, run_snakemake
from scipy.special import betainc, betaln

from mjtrial import provenance
from mjtrial.files.layout import Layout
from mjtrial.stats.sequential import calibrated_threshold
from mjtrial.verify import Status, verify_results

pytestmark = pytest.mark.end_to_end

LAYOUT = Layout.of("research_mode")


def guide_stopping() -> dict:
    """The `stopping` section docs/guide/statistics.md gives, as it is written there."""
    guide = (REPO_ROOT / "docs" / "guide" / "statistics.md").read_text()
    block = re.search(r"```yaml\n(stopping:\n.*?)```", guide, re.S)
    return yaml.safe_load(block[1])["stopping"]


SHIPPED = yaml.safe_load((REPO_ROOT / "config" / "config.yaml").read_text())
N, SHARD = SHIPPED["states"]["n"], guide_stopping()["look_every"]
SHARDS = [f"{i:05d}" for i in range((N + SHARD - 1) // SHARD)]
THRESHOLD = calibrated_threshold(N, guide_stopping()["alpha"])["threshold"]


def planned_jobs(workdir: Path, *args: str) -> list[tuple[str, list[str], list[str]]]:
    """(rule, outputs, inputs) of every job a dry run of every job plans."""
    out = run_snakemake(workdir, "-n", "--forceall", *args).stdout
    jobs = []
    for block in re.split(r"^(?:local)?(?:rule|checkpoint) ", out, flags=re.MULTILINE)[1:]:
        rule = block.split(":", 1)[0]
        files = {
            m[1]: m[2].split(", ") for m in re.finditer(r"^    (input|output): (.*)$", block, re.M)
        }
        jobs.append((rule, files.get("output", []), files.get("input", [])))
    return jobs


def test_without_a_stopping_section_the_plan_is_every_shard_and_no_look(tmp_path):
    workdir = copy_workflow(tmp_path)
    edit_config(workdir, lambda c: (c["states"].update(n=12), c["rollout"].update(shard_size=5)))
    jobs = planned_jobs(workdir)
    counts: dict[str, int] = {}
    for rule, _, _ in jobs:
        counts[rule] = counts.get(rule, 0) + 1
    assert counts == {
        "states": 1,
        "register": 1,
        "rollout": 6,
        "gather": 2,
        "failures": 1,
        "analysis": 1,
        "figures": 1,
        "manifest": 1,
        "report": 1,
        "seal": 1,
        "crate": 1,
        "all": 1,
    }
    shards = [
        f"{LAYOUT.shard_table(c, s)}" for c in ("fast", "slow") for s in ("00000", "00001", "00002")
    ]
    by_rule = {rule: (outputs, inputs) for rule, outputs, inputs in jobs}
    for rule in ("manifest", "seal", "all"):
        assert set(shards) <= set(by_rule[rule][1]), rule
    assert not any("looks" in f for _, outputs, inputs in jobs for f in outputs + inputs)


def test_with_a_stopping_section_the_first_plan_stops_at_the_first_look(tmp_path):
    workdir = copy_workflow(tmp_path)
    edit_config(workdir, with_stopping)
    jobs = planned_jobs(workdir)
    rollouts = sorted(o for rule, outputs, _ in jobs if rule == "rollout" for o in outputs)
    assert all("shard-00000" in o for o in rollouts) and len(rollouts) == 4  # tables, folders
    looks = [(outputs, inputs) for rule, outputs, inputs in jobs if rule == "look"]
    assert looks == [
        (
            [str(LAYOUT.look("00000"))],
            [str(LAYOUT.shard_table("slow", "00000")), str(LAYOUT.shard_table("fast", "00000"))],
        )
    ]


def with_stopping(config) -> None:
    """The shipped config (N = 200, shards of 1,000 states) with the guide's stopping rule."""
    config["stopping"] = guide_stopping()


def e_value(wins: int, discordant: int) -> float:
    """The one-sided Beta(1, 1) mixture against p = 1/2, written out here."""
    upper = 1.0 - betainc(wins + 1, discordant - wins + 1, 0.5)
    return 2.0 ** (discordant + 1) * math.exp(betaln(wins + 1, discordant - wins + 1)) * upper


@pytest.fixture(scope="module")
def stopped(tmp_path_factory) -> Path:
    """The shipped gantry experiment with the guide's stopping rule, built."""
    workdir = copy_workflow(tmp_path_factory.mktemp("stopping"))
    edit_config(workdir, with_stopping)
    run_snakemake(workdir)
    return workdir


def test_the_guides_example_stops_early_on_the_shipped_config(stopped):
    root = stopped
    ran = [s for s in SHARDS if (root / LAYOUT.shard_table("slow", s)).exists()]
    assert 0 < len(ran) < len(SHARDS)  # it stopped early
    # the stop recomputed from the shard tables: the first look whose e-value reaches 20
    slow = [
        bool(x)
        for s in ran
        for x in pq.read_table(root / LAYOUT.shard_table("slow", s))["success"].to_pylist()
    ]
    fast = [
        bool(x)
        for s in ran
        for x in pq.read_table(root / LAYOUT.shard_table("fast", s))["success"].to_pylist()
    ]
    expected = []
    for i in range(len(ran)):
        pairs = list(zip(slow[: (i + 1) * SHARD], fast[: (i + 1) * SHARD], strict=True))
        wins = sum(a and not b for a, b in pairs)
        losses = sum(b and not a for a, b in pairs)
        expected.append(e_value(wins, wins + losses))
    assert all(e < THRESHOLD for e in expected[:-1]) and expected[-1] >= THRESHOLD
    for shard in SHARDS[len(ran) :]:
        for condition in ("slow", "fast"):
            assert not (root / LAYOUT.shard_table(condition, shard)).exists()
            assert not (root / LAYOUT.shard_recordings(condition, shard)).exists()
        assert not (root / LAYOUT.look(shard)).exists()
    for i, shard in enumerate(ran):
        look = json.loads((root / LAYOUT.look(shard)).read_text())
        assert look["stop"] == (i == len(ran) - 1)
        assert look["looks"][-1]["e_value"] == pytest.approx(expected[i], rel=1e-9)

    summary = json.loads((root / LAYOUT.summary).read_text())
    n_used = len(ran) * SHARD
    assert summary["n_states"] == n_used
    assert summary["conditions"]["slow"]["n"] == n_used
    record = summary["stopping"]
    assert record["n_used"] == n_used and record["max_n"] == N and record["look_every"] == SHARD
    assert record["threshold"] == THRESHOLD < 1 / record["alpha"]
    assert summary["falsifier"]["verdict"] == "survives"  # the rule's test decides it
    assert record["rejected"] and record["stopped_at_look"] == len(ran) - 1
    assert [look["e_value"] for look in record["looks"]] == pytest.approx(expected, rel=1e-9)
    assert pq.read_table(root / LAYOUT.rollout_table("slow")).num_rows == n_used

    manifest = json.loads((root / LAYOUT.manifest).read_text())
    assert manifest["results"]["stopping"] == record
    assert {str(LAYOUT.look(s)) for s in ran} <= set(manifest["stamps"])
    report = (root / LAYOUT.report).read_text()
    assert "## Stopping early" in report
    assert f"Stopped at look {len(ran) - 1}, after {n_used} of {N} states" in report


def test_a_stopped_run_verifies_and_a_forged_look_is_named(stopped, tmp_path):
    config = stopped / "config" / "config.yaml"
    report = verify_results(
        stopped / LAYOUT.root, config_path=config, repo_root=stopped, resimulate=1, seed=1
    )
    assert report.ok, report.format()
    look = stopped / LAYOUT.look("00000")
    original = look.read_bytes()
    try:
        record = json.loads(original)
        stamp = record.pop("provenance")
        record["looks"][-1]["e_value"] *= 2
        provenance.write_json(record, look, stamp)
        forged = verify_results(
            stopped / LAYOUT.root, config_path=config, repo_root=stopped, resimulate=0, seed=1
        )
        assert forged.status_of(str(LAYOUT.look("00000"))) == Status.TAMPERED
    finally:
        look.write_bytes(original)
