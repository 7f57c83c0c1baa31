"""Snakemake runs forked from a process that has already imported it, for the tests.

Most of the suite's time went to starting Snakemake: each `snakemake` process imports Snakemake,
pandas (its parameter check), MuJoCo and the workflow's own modules, about 2 s of CPU before the
first rule, and the suite starts it several hundred times. `run` instead asks a server process
(this file run as a script, one per test worker) that imported all of that once; the server
forks a child per run, and the child runs Snakemake's own command line (`snakemake.cli.main`) in
the run's folder and environment, its output to files, its exit status the run's. The child is
what a fresh `snakemake` process would be, less the import time: the same entry point, the same
arguments. Its Python job scripts (`script:` rules) are started by Snakemake as ever, through
`job_launcher.py`, and run forked from a second server that imported their modules
(`forked_jobs`).

A run that changes `PYTHONPATH` (another copy of the package) is not forked: the server's modules
come from this checkout. `tests/conftest.py`'s `run_snakemake` decides.
"""

from __future__ import annotations

import functools
import json
import os
import select
import signal
import subprocess
import sys
import tempfile
from pathlib import Path

# What a Snakemake run of this workflow imports before its first job (a dry run's new modules,
# the large ones): imported once by the server.
PRELOAD = (
    "snakemake.cli",
    "snakemake.api",
    "snakemake.dag",
    "snakemake.workflow",
    "snakemake.persistence",
    "snakemake.executors.local",
    "pandas",  # Snakemake's check of changed parameters imports it
    "mujoco",
    "numpy",
    "pyarrow.parquet",
    "yaml",
    "jsonschema",
    "mjtrial.config",
    "mjtrial.config.check",
    "mjtrial.task.checks",
    "mjtrial.stages.stamping",
    "mjtrial.workflow_script",
    "mjtrial.design.registration",
    "mjtrial.design.conditions",
    "mjtrial.sim.simenv",
    "mjtrial.sim.physics",
    "mjtrial.files.safekeeping",
    "mjtrial.files.layout",
    "mjtrial.provenance",
    "mjtrial.provenance.recording_folders",
    "mjtrial.benchmark",
    "mjtrial.benchmark.config",
    "mjtrial.policy_files.file",
    # the stages Snakemake's own process runs (`run:` rules), with rerun and matplotlib
    "mjtrial.recording",
    "mjtrial.stages.states",
    "mjtrial.stages.register",
    "mjtrial.stages.rollout",
    "mjtrial.stages.failures",
    "mjtrial.stages.analysis",
    "mjtrial.stages.report",
    "mjtrial.report.figures",
    "mjtrial.stages.manifest",
    "mjtrial.stages.seal",
    "mjtrial.stages.crate",
    "mjtrial.stages.look",
    "mjtrial.stages.evaluate",
    "mjtrial.stages.pilot",
    "mjtrial.stages.studies",
    "mjtrial.stages.benchmark",
    "scipy.special",
)


def _child(request: dict, jobs: str) -> None:
    """Run Snakemake as the request says, its Python job scripts through the job server at
    `jobs`."""
    import forked_jobs

    os.setsid()  # its own process group: a timeout kills the run and its jobs
    os.chdir(request["cwd"])
    os.environ.clear()
    os.environ.update(request["env"])
    forked_jobs.use(jobs)
    null = os.open(os.devnull, os.O_RDONLY)
    os.dup2(null, 0)
    for fd, path in ((1, request["stdout"]), (2, request["stderr"])):
        out = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o644)
        os.dup2(out, fd)
        os.close(out)
    sys.argv = [request["executable"], *request["argv"]]
    import snakemake.cli

    snakemake.cli.main(request["argv"])


def _collect_plugins() -> None:
    """Snakemake's plugin registries, each found once: a registry is a process-wide singleton
    that scans every installed module for its plugins when first made (0.6 s of each run's
    start, measured with cProfile in a forked run)."""
    from snakemake_interface_common.plugin_registry import PluginRegistryBase

    registries = [PluginRegistryBase]
    while registries:
        registry = registries.pop()
        registries += registry.__subclasses__()
        if registry is not PluginRegistryBase:
            registry()


def serve() -> None:
    """The server: one request per line on stdin; answers the child's pid, then its status."""
    import importlib

    import forked_jobs

    jobs = forked_jobs.start()
    for name in PRELOAD:
        importlib.import_module(name)
    _collect_plugins()
    reply = os.fdopen(os.dup(1), "w")
    os.dup2(os.open(os.devnull, os.O_WRONLY), 1)  # nothing else may write into the replies
    reply.write("ready\n")
    reply.flush()
    for line in sys.stdin:
        request = json.loads(line)
        pid = os.fork()
        if pid == 0:
            forked_jobs.exit_as_interpreter(functools.partial(_child, request, jobs))
        reply.write(f"{pid}\n")
        reply.flush()
        _, status = os.waitpid(pid, 0)
        reply.write(f"{os.waitstatus_to_exitcode(status)}\n")
        reply.flush()


class _Server:
    def __init__(self) -> None:
        self.proc = subprocess.Popen(
            [sys.executable, __file__],
            stdin=subprocess.PIPE,
            stdout=subprocess.PIPE,
            text=True,
            bufsize=1,
        )
        if self._line(timeout=300) != "ready":
            raise RuntimeError("the Snakemake server did not start")

    def alive(self) -> bool:
        return self.proc.poll() is None

    def _line(self, timeout: float | None) -> str:
        if timeout is not None:
            ready, _, _ = select.select([self.proc.stdout], [], [], timeout)
            if not ready:
                raise TimeoutError
        line = self.proc.stdout.readline()
        if not line:
            raise RuntimeError("the Snakemake server exited")
        return line.strip()

    def run(self, executable: str, argv: list[str], cwd: Path, env: dict, timeout: float):
        with tempfile.TemporaryDirectory(prefix="mjtrial-snakemake-") as folder:
            out, err = Path(folder, "stdout"), Path(folder, "stderr")
            request = {
                "executable": executable,
                "argv": argv,
                "cwd": str(cwd),
                "env": env,
                "stdout": str(out),
                "stderr": str(err),
            }
            self.proc.stdin.write(json.dumps(request) + "\n")
            self.proc.stdin.flush()
            pid = int(self._line(timeout=60))
            try:
                code = int(self._line(timeout=timeout))
            except TimeoutError:
                os.killpg(pid, signal.SIGKILL)
                self._line(timeout=60)
                raise subprocess.TimeoutExpired([executable, *argv], timeout) from None
            return subprocess.CompletedProcess(
                [executable, *argv],
                code,
                out.read_text(errors="replace"),
                err.read_text(errors="replace"),
            )


_server: _Server | None = None


def run(executable: str, argv: list[str], cwd: Path, env: dict, timeout: float):
    """`subprocess.run([executable, *argv], cwd=cwd, env=env, capture_output=True, text=True,
    timeout=timeout)` for Snakemake, forked from the server."""
    global _server
    if _server is None or not _server.alive():
        _server = _Server()
    return _server.run(executable, argv, cwd, env, timeout)


if __name__ == "__main__":
    serve()
