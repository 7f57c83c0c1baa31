"""Snakemake's Python job scripts forked from a process that imported their modules once, for
the tests.

A job script (a `script:` rule: a rollout shard, an evaluation, the failures' gather) is a new
Python process, and most of a small test build's job is its imports: MuJoCo, pyarrow, rerun,
Snakemake's own modules to unpickle its `snakemake` object, the stage. In the tests, Snakemake
(itself forked, `forked_snakemake`) starts `job_launcher.py` instead of `python script.py`; the
launcher, a bare interpreter (`-S -I`), hands its argv, folder, environment and standard streams
to this server, which forks a child that imported all of that already. The child runs the
script as `python script.py` would (`runpy`, `__main__`, the script's folder first on the path)
in its own process group; its exit status (or signal) is the launcher's. If the launcher is
killed (a timeout, Snakemake stopping the job), the child's group is killed with it.

A job whose environment differs from the server's in what an interpreter reads as it starts or
as numpy loads (`PYTHON*`, the BLAS thread counts Snakemake sets from a job's `threads`, `LD_*`)
is started fresh, as are jobs in a conda env or container. The server starts with the thread
counts of a one-thread job, the workflow's rollouts.
"""

from __future__ import annotations

import functools
import json
import os
import select
import signal
import socket
import subprocess
import sys
import tempfile
from collections.abc import Callable
from pathlib import Path
from typing import NoReturn

ADDRESS = "MJTRIAL_TEST_JOB_SERVER"  # the environment variable naming the server's socket
LAUNCHER = Path(__file__).with_name("job_launcher.py")

# What the workflow's job scripts import (rollout, gather's shards, evaluation, training,
# solvability, pilot, failures), with what Snakemake's preamble unpickles with.
PRELOAD = (
    "snakemake.io",
    "snakemake.iocontainers",
    "snakemake.logging",
    "snakemake.script",
    "mujoco",
    "numpy",
    "pyarrow.parquet",
    "mjtrial.sim.simenv",
    "mjtrial.workflow_script",
    "mjtrial.recording",
    "mjtrial.stages.rollout",
    "mjtrial.stages.failures",
    "mjtrial.stages.pilot",
    "mjtrial.stages.evaluate",
    "mjtrial.stages.train",
    "mjtrial.stages.benchmark",
)

# The variables Snakemake sets from a job's threads; the server's are a one-thread job's.
THREAD_VARIABLES = (
    "OMP_NUM_THREADS",
    "GOTO_NUM_THREADS",
    "OPENBLAS_NUM_THREADS",
    "MKL_NUM_THREADS",
    "VECLIB_MAXIMUM_THREADS",
    "NUMEXPR_NUM_THREADS",
)
# Prefixes of the variables read before a script's first line: a job that differs in one is
# started fresh.
AT_START = ("PYTHON", "LD_", "MALLOC", *THREAD_VARIABLES)


def _at_start(env: dict) -> dict:
    return {k: v for k, v in env.items() if k.startswith(AT_START)}


def _exit_code(exc: SystemExit) -> int:
    if exc.code is None:
        return 0
    if isinstance(exc.code, int):
        return exc.code
    print(exc.code, file=sys.stderr)  # what the interpreter does with sys.exit("message")
    return 1


def exit_as_interpreter(main: Callable[[], None]) -> NoReturn:
    """Run `main` in this forked child and leave it as a fresh interpreter would: status 0, a
    `SystemExit`'s code, or 1 with the traceback printed; exit functions run, streams flushed."""
    import atexit

    code = 1
    try:
        try:
            main()
            code = 0
        except SystemExit as exc:
            code = _exit_code(exc)
        atexit._run_exitfuncs()
    except BaseException:  # anything else is the failure, printed as the interpreter would
        import traceback

        traceback.print_exc()
        code = 1
    finally:
        for stream in (sys.stdout, sys.stderr):
            try:
                stream.flush()
            except Exception:
                pass
        os._exit(code)


def _script(request: dict, fds: list[int]) -> None:
    """Run the job's script as `python script.py` would."""
    import runpy

    os.setpgid(0, 0)
    for target, fd in enumerate(fds):
        os.dup2(fd, target)
        os.close(fd)
    os.chdir(request["cwd"])
    os.environ.clear()
    os.environ.update(request["env"])
    script = request["argv"][0]
    sys.argv = list(request["argv"])
    sys.path[0] = os.path.dirname(os.path.abspath(script))
    runpy.run_path(script, run_name="__main__")


def _receive(conn: socket.socket) -> tuple[dict, list[int]]:
    head, fds, _, _ = socket.recv_fds(conn, 8, 3)
    while len(head) < 8:
        head += conn.recv(8 - len(head))
    size = int.from_bytes(head, "big")
    body = b""
    while len(body) < size:
        chunk = conn.recv(size - len(body))
        if not chunk:
            raise ConnectionError("the launcher left before its request was read")
        body += chunk
    return json.loads(body), fds


def _job(conn: socket.socket) -> None:
    """One job: run its script in a child, answer its exit status, kill it if the launcher goes."""
    code = 0
    try:
        signal.signal(signal.SIGCHLD, signal.SIG_DFL)
        request, fds = _receive(conn)
        if _at_start(request["env"]) != _at_start(dict(os.environ)):
            conn.sendall(b"exec\n")
            os._exit(0)
        pid = os.fork()
        if pid == 0:
            conn.close()
            exit_as_interpreter(functools.partial(_script, request, fds))
        for fd in fds:
            os.close(fd)
        done = os.pidfd_open(pid)
        while True:
            ready, _, _ = select.select([conn, done], [], [])
            if done in ready:
                _, status = os.waitpid(pid, 0)
                conn.sendall(f"{os.waitstatus_to_exitcode(status)}\n".encode())
                break
            if not conn.recv(1):  # the launcher was killed: so is its job
                os.killpg(pid, signal.SIGKILL)
                os.waitpid(pid, 0)
                break
    except BaseException:
        import traceback

        traceback.print_exc()
        code = 1
    finally:
        os._exit(code)


def serve(address: str) -> None:
    """The server: import the jobs' modules, then fork a child per connection until the process
    that started it (the Snakemake server) is gone."""
    import importlib

    from mjtrial.nopandas import pyarrow_without_pandas

    pyarrow_without_pandas()  # as the rollout script does before importing pyarrow
    for name in PRELOAD:
        importlib.import_module(name)
    parent = os.getppid()
    listener = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
    listener.bind(address)
    listener.listen(64)
    signal.signal(signal.SIGCHLD, signal.SIG_IGN)  # each job's child reaped by the kernel
    print("ready", flush=True)
    try:
        while os.getppid() == parent:
            ready, _, _ = select.select([listener], [], [], 1.0)
            if not ready:
                continue
            conn, _ = listener.accept()
            sys.stdout.flush()
            sys.stderr.flush()
            if os.fork() == 0:
                listener.close()
                _job(conn)
            conn.close()
    finally:
        listener.close()
        Path(address).unlink(missing_ok=True)
        Path(address).parent.rmdir()


def start() -> str:
    """Start a server as a child of this process; return its socket's path."""
    address = str(Path(tempfile.mkdtemp(prefix="mjtrial-jobs-"), "socket"))
    env = os.environ | {name: "1" for name in THREAD_VARIABLES}
    proc = subprocess.Popen(
        [sys.executable, __file__, address], stdout=subprocess.PIPE, env=env, text=True
    )
    ready, _, _ = select.select([proc.stdout], [], [], 300)
    if not ready or proc.stdout.readline().strip() != "ready":
        raise RuntimeError("the job server did not start")
    proc.stdout.close()
    return address


def use(address: str) -> None:
    """In a Snakemake process: run its Python job scripts through the server at `address`."""
    from snakemake.script import PythonScript

    fresh = PythonScript.execute_script

    def execute_script(self, fname, edit=False):
        if self.container_img is not None or self.conda_env is not None or self.env_modules:
            return fresh(self, fname, edit)
        self._execute_cmd(
            "{python} -S -I {launcher:q} {fname:q}",
            python=sys.executable,
            launcher=str(LAUNCHER),
            fname=fname,
            is_python_script=True,
        )

    os.environ[ADDRESS] = address
    PythonScript.execute_script = execute_script


if __name__ == "__main__":
    serve(sys.argv[1])
