"""A job in a process of its own ends with the Snakemake process that started it: a killed
`snakemake` leaves no job running, and no job writes an output after the run died."""

from __future__ import annotations

import os
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import psutil
import pytest
from conftest import SNAKEMAKE

pytestmark = pytest.mark.end_to_end

RESULTS = Path("results") / "research_mode"


def _rollout_jobs(snakemake: psutil.Process) -> list[psutil.Process]:
    jobs = []
    for child in snakemake.children(recursive=True):
        try:
            if any(part.endswith(".rollout.py") for part in child.cmdline()):
                jobs.append(child)
        except psutil.NoSuchProcess:
            pass
    return jobs


def _running(job: psutil.Process) -> bool:
    """Alive (an ended job nobody has reaped yet is a zombie: not running)."""
    try:
        return job.status() != psutil.STATUS_ZOMBIE
    except psutil.NoSuchProcess:
        return False


def test_a_killed_snakemake_leaves_no_job_running_or_writing(built, tmp_path):
    workdir = tmp_path / "copy"
    shutil.copytree(built, workdir)
    results = workdir / RESULTS
    for log in (results / "logs").glob("rollout_*.log"):
        log.unlink()
    proc = subprocess.Popen(
        [SNAKEMAKE, "-c2", "--forcerun", "rollout"],
        cwd=workdir,
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
        start_new_session=True,
    )
    snakemake, jobs = psutil.Process(proc.pid), []
    try:
        deadline = time.monotonic() + 120
        # A job is running its stage once it has written its log (after it started).
        while time.monotonic() < deadline and proc.poll() is None:
            jobs = _rollout_jobs(snakemake)
            if jobs and list((results / "logs").glob("rollout_*.log")):
                break
            time.sleep(0.02)
        assert jobs and proc.poll() is None, "no rollout job ran before the run ended"
        os.kill(proc.pid, signal.SIGKILL)  # Snakemake only, not its jobs
        proc.wait()
        killed = time.time()
        while time.time() < killed + 5 and any(map(_running, jobs)):
            time.sleep(0.05)
        alive = [job.pid for job in jobs if _running(job)]
        assert not alive, f"jobs still running 5 s after snakemake was killed: {alive}"
        time.sleep(1)
        written = [
            p for p in results.rglob("*") if p.is_file() and p.stat().st_mtime > killed + 0.1
        ]
        assert not written, f"written after snakemake was killed: {written}"
    finally:
        for job in jobs:
            try:
                job.kill()
            except psutil.NoSuchProcess:
                pass
        if proc.poll() is None:
            proc.kill()


def test_a_job_whose_snakemake_is_gone_does_nothing(tmp_path, monkeypatch):
    """Snakemake killed while the job imported: the job exits at once, writing nothing."""
    gone = subprocess.Popen([sys.executable, "-c", "pass"])
    gone.wait()  # a Snakemake process that no longer exists
    log = tmp_path / "job.log"
    code = (
        "from types import SimpleNamespace\n"
        "from mjtrial.workflow_script import run_job\n"
        f"job = SimpleNamespace(log=[{str(log)!r}], params={{}}, input={{}})\n"
        f"run_job(job, lambda: open({str(tmp_path / 'out')!r}, 'w'), rule='states')\n"
    )
    env = {**os.environ, "MJTRIAL_WORKFLOW_PID": str(gone.pid)}
    proc = subprocess.run(
        [sys.executable, "-c", code], env=env, capture_output=True, text=True, timeout=60
    )
    assert proc.returncode == 1
    assert proc.stderr == (
        f"error: the Snakemake process {gone.pid} that started this job is gone\n"
    )
    assert not log.exists() and not (tmp_path / "out").exists()


def test_a_killed_process_not_yet_reaped_counts_as_gone():
    """A job checks its Snakemake right after its imports; killed but not yet reaped, that
    process is a zombie: it exists, and is dead."""
    from mjtrial.workflow_script import _alive

    child = subprocess.Popen(["sleep", "30"])
    child.kill()
    deadline = time.monotonic() + 10
    while psutil.Process(child.pid).status() != psutil.STATUS_ZOMBIE:
        assert time.monotonic() < deadline
        time.sleep(0.01)
    assert not _alive(child.pid)
    child.wait()
    assert not _alive(child.pid) and _alive(os.getpid())
