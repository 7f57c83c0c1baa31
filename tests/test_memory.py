"""Memory: what Snakemake's own process imports, and the peak a job process reports.

Snakemake's process runs the light jobs in threads, so every library the workflow's files
import stays in it for the whole run (the 400 MB bar of `benchmarks/bench_memory.py`).
"""

from __future__ import annotations

import re
import subprocess
import sys

import numpy as np
import pytest

from mjtrial import REPO_ROOT
from mjtrial.sim import engine
from mjtrial.sim.engine import iter_batches
from mjtrial.task import BoundTask, load_task

pytestmark = pytest.mark.end_to_end

# Libraries no job of Snakemake's process needs: pycma (which imports scipy.stats and
# matplotlib, 52 MB) tunes a method in the train job, a process of its own; statsmodels is the
# dose-response study's.
NOT_IN_SNAKEMAKE = ("cma", "scipy.stats", "statsmodels")


def workflow_imports() -> list[str]:
    """The package modules the Snakefile and the rule files import."""
    files = [REPO_ROOT / "Snakefile", *sorted((REPO_ROOT / "workflow/rules").glob("*.smk"))]
    text = "\n".join(f.read_text(encoding="utf-8") for f in files)
    return sorted(set(re.findall(r"^\s*from (mjtrial[\w.]*) import", text, re.MULTILINE)))


def test_the_workflow_files_import_no_library_only_a_job_process_needs():
    modules = workflow_imports()
    assert "mjtrial.benchmark.config" in modules  # the list is read, not empty
    code = (
        "import importlib, sys\n"
        f"for m in {modules!r}: importlib.import_module(m)\n"
        f"print([m for m in {NOT_IN_SNAKEMAKE!r} if m in sys.modules])\n"
    )
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert proc.stdout.strip() == "[]"


def test_a_job_process_reports_its_own_peak_not_its_parents():
    """Snakemake starts a job's process from its own, holding hundreds of MB; the job's log must
    give the job's peak, not the parent's (`ru_maxrss` keeps the image before `exec`)."""
    held_mb = 300
    code = (
        "import subprocess, sys\n"
        f"held = bytearray({held_mb} * 2**20)\n"
        "for i in range(0, len(held), 4096): held[i] = 1\n"  # resident, not only reserved
        "child = 'from mjtrial.workflow_script import resources_line; print(resources_line())'\n"
        "print(subprocess.run([sys.executable, '-c', child], capture_output=True, text=True,\n"
        "    check=True).stdout)\n"
    )
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    peak = float(re.search(r"peak rss (\d+) MB", proc.stdout).group(1))
    assert 0 < peak < held_mb / 2, proc.stdout  # the child imports little: tens of MB


def _array_bytes(batch) -> int:
    e = batch.episodes
    return e.physics.nbytes + e.sensordata.nbytes + np.asarray(e.ctrl).nbytes


def test_a_batch_holds_what_its_size_was_chosen_for_and_a_short_episode_runs_many():
    """The engine sizes a batch by bytes (`engine.BATCH_BYTES`, counting each array twice:
    the engine's and the recording writer's): the arrays a batch really holds stay within half
    of it, and are more than half of it when another episode would have fit; the cart-pole's
    short episodes run many to a batch (a closed-loop policy is called once per batch)."""
    cases = {}
    for name in ("gantry_lift", "cartpole_latency"):
        bound = BoundTask.of(load_task(REPO_ROOT / "tasks" / name / "task.py"))
        rng = np.random.default_rng(0)
        n = 300
        values = {p.name: rng.uniform(p.low, p.high, n) for p in bound.task.state_parameters}
        thresholds = {t.name: t.default for t in bound.task.thresholds}
        first = next(iter_batches(bound, values, {}, thresholds=thresholds))
        size = len(first.outcome["success"])
        held = _array_bytes(first)
        assert held <= engine.BATCH_BYTES / 2
        if size < min(n, engine.MAX_BATCH):
            assert held + held / size > engine.BATCH_BYTES / 2
        cases[name] = size
    assert cases["cartpole_latency"] >= 100
    assert cases["gantry_lift"] < cases["cartpole_latency"]
