"""What every Snakemake script shares: the rule's log, its stamp line, and one-line errors.

A workflow script runs either as Snakemake's `script:` (a process of its own: the rollouts,
whose memory is bounded by their shard and which a SLURM cluster spreads over nodes) or inside
Snakemake's own process, from a rule's `run:` block (`run_in_process`): the light stages, for
which a process of their own would cost more in interpreter start-up and imports (about 1 s of
CPU each) than their work. Both run the same script with the same `snakemake` object.
"""

from __future__ import annotations

import ctypes
import gc
import importlib
import inspect
import json
import logging
import os
import resource
import signal
import sys
import threading
import time
import traceback
from collections.abc import Callable, Iterable, Iterator
from contextlib import contextmanager
from functools import cache
from pathlib import Path
from types import CodeType, SimpleNamespace
from typing import Any

from mjtrial import provenance
from mjtrial.files.layout import COMPILED_MODELS, Layout
from mjtrial.sim.simenv import run_in_env
from mjtrial.stages.stamping import make_stage_stamp

log = logging.getLogger("mjtrial")
log.setLevel(logging.INFO)


class JobFailed(Exception):
    """A job that ran inside Snakemake's process failed; its log holds the traceback."""


def run_job(snakemake: Any, stage: Callable[..., Any], /, *, rule: str, **kwargs: Any) -> None:
    """Run one job of a stage: the log begins with the job's stamp; a failure is one line.

    Args:
      snakemake: the `snakemake` object Snakemake gives the script.
      stage: the `mjtrial.stages` function the job calls with `kwargs`.
      rule: the stamp's rule, `<stage>` or `<stage>:<qualifier>` (`rollout:fast`).

    On failure the console and the log get one line, `error: <rule>: <message>`; the log also
    gets the traceback below it, for a bug. A job in its own process exits with status 1; a job
    inside Snakemake's process raises `JobFailed`. The log's last line on success gives the
    job's wall time, CPU time and peak memory (`resources_line`).
    """
    in_process = getattr(snakemake, "in_process", False)
    if not in_process:
        run_in_env(snakemake)  # a variant's other MuJoCo version: its own environment's Python
        die_with_workflow()
        from mjtrial.sim.physics import keep_compiled_models  # after run_in_env: imports MuJoCo

        keep_compiled_models(COMPILED_MODELS)  # the model Snakemake's process compiled
    elif snakemake.input.get("simulator_env"):
        raise JobFailed(f"{rule}: a job in another MuJoCo's environment needs a process of its own")
    log_path = Path(snakemake.log[0])
    log_path.parent.mkdir(parents=True, exist_ok=True)
    registered = provenance.REGISTRATION_SHA256.set(registration_of(log_path))
    try:
        _run_job(snakemake, stage, rule, kwargs, log_path, in_process)
    finally:
        provenance.REGISTRATION_SHA256.reset(registered)


def registration_of(log_path: Path) -> str | None:
    """The sha256 of the registration the job runs under (`registration.entry_sha256`): that of
    the results folder its log lies in (`<results>/logs/`), None before there is one (the
    states job of a first run, the pilot's jobs under `development/`)."""
    path = Layout(log_path.parent.parent).registration
    try:
        current = json.loads(provenance.read_output_text(path))["current"]
    except (OSError, ValueError, KeyError, TypeError):
        return None
    sha = current.get("sha256") if isinstance(current, dict) else None
    return sha if isinstance(sha, str) else None


def _run_job(
    snakemake: Any,
    stage: Callable[..., Any],
    rule: str,
    kwargs: dict[str, Any],
    log_path: Path,
    in_process: bool,
) -> None:
    started = time.monotonic(), time.thread_time()
    stamp = make_stage_stamp(
        rule, snakemake.params.get("slice", {}), dict(snakemake.input.items()), repo_root=Path.cwd()
    )
    # a process of its own: what its start and imports cost, in its log only (the profile's)
    entered = "" if in_process else f"{entered_line()}\n"
    log_path.write_text(provenance.log_stamp_line(stamp) + "\n" + entered, encoding="utf-8")
    if "rule" in inspect.signature(stage).parameters:  # stages that stamp per job take it too
        kwargs["rule"] = rule
    with (
        job_log(log_path),
        job_output(log_path, whole_process=not in_process),
        _in_process_job(in_process),
    ):
        try:
            stage(**kwargs)
        except Exception as err:  # noqa: BLE001 - every failure is reported the same way
            # Paths relative to the working folder: a log travels with the results.
            here = f"{Path.cwd()}{os.sep}"
            message = " ".join(str(err).split()).replace(here, "") or type(err).__name__
            log.error("error: %s: %s", rule, message)
            with open(log_path, "a", encoding="utf-8") as f:
                f.write("".join(traceback.format_exception(err)).replace(here, ""))
            if in_process:
                raise JobFailed(f"{rule}: {message} (traceback in {log_path})") from None
            sys.exit(1)
        if in_process:
            log.info("%s", thread_resources_line(*started))
        else:
            log.info("%s", resources_line())
    if not in_process:
        # Done, its outputs written: the process exits next, and the interpreter's exit walks
        # every object left (numpy, MuJoCo, Rerun, the task) in collections that free nothing
        # the exit would not: 0.17-0.21 s of a rollout job's process, 0.04 s once frozen.
        gc.freeze()


ERROR_LINE = "error: "  # how `run_job`'s one-line reason for a failure begins, in the log
FAILURES_SHOWN = 5  # failed jobs whose reasons the console repeats at the end of a run


def failure_reasons(logs: Iterable[str | Path], *, shown: int = FAILURES_SHOWN) -> list[str]:
    """The failed jobs' one-line reasons, read from their logs, for the end of the console.

    A job in a process of its own (a rollout) prints its reason where it fails, and Snakemake
    then prints the other jobs it waits for and its own error block, ending on "At least one
    job did not complete successfully"; on a cluster the job's console is not the user's at
    all. So the workflow's `onerror` repeats each failed job's `error: <rule>: <message>` (the
    line `run_job` writes before the traceback) with its log's path; for a job that died
    without one (killed, out of memory, a crash in native code) it says so, with the log's last
    line. At most `shown` lines, then how many more failed.
    """
    paths = list(dict.fromkeys(str(p) for p in logs))
    lines = []
    for path in paths[:shown]:
        try:
            text = Path(path).read_text(encoding="utf-8", errors="replace").splitlines()
        except OSError:
            lines.append(f"error: a job failed before writing its log {path}")
            continue
        end = next((i for i, t in enumerate(text) if t.startswith("Traceback")), len(text))
        reason = [t for t in text[:end] if t.startswith(ERROR_LINE)]
        if reason:
            lines.append(f"{reason[-1]} (its log: {path})")
            continue
        last = next((t for t in reversed(text) if t.strip()), "(empty)")
        lines.append(
            f"error: a job stopped without saying why (killed, out of memory or crashed); its "
            f"log {path} ends: {last.strip()}"
        )
    if len(paths) > shown:
        lines.append(f"error: and {len(paths) - shown} more failed jobs: see their logs")
    return lines


# The Snakemake process that starts the jobs, by its pid, for a job in a process of its own.
WORKFLOW_PID = "MJTRIAL_WORKFLOW_PID"
_PR_SET_PDEATHSIG = 1  # linux/prctl.h


def mark_workflow_process() -> None:
    """Record this process (a Snakemake process that starts jobs: run.smk calls this) as the
    one its jobs' processes live with (`die_with_workflow`)."""
    os.environ[WORKFLOW_PID] = str(os.getpid())


def die_with_workflow() -> None:
    """Make a job in a process of its own end with the Snakemake process that started it.

    A killed Snakemake leaves its `script:` jobs running (their parent is Snakemake itself), and
    an orphaned job would write its output after the run died. On Linux the kernel kills the
    job when its parent dies (`PR_SET_PDEATHSIG`); a job whose Snakemake died before it got
    here (while it imported) exits at once, having done nothing.
    """
    if sys.platform.startswith("linux"):
        try:
            ctypes.CDLL(None, use_errno=True).prctl(_PR_SET_PDEATHSIG, signal.SIGKILL)
        except (OSError, AttributeError):
            pass
    workflow = os.environ.get(WORKFLOW_PID, "")
    if workflow.isdigit() and os.getppid() != int(workflow) and not _alive(int(workflow)):
        print(
            f"error: the Snakemake process {workflow} that started this job is gone",
            file=sys.stderr,
        )
        os._exit(1)


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)  # no signal: only whether the process exists
    except ProcessLookupError:
        return False
    except PermissionError:  # it exists, and is another user's
        pass
    # A killed process stays a zombie until its parent reaps it: dead, though it exists (a job
    # that checked in that window ran to its end after its Snakemake was killed, under load).
    try:
        state = Path(f"/proc/{pid}/stat").read_text().rpartition(")")[2].split()[0]
    except (OSError, IndexError):
        return True
    return state not in ("Z", "X")


class _ThreadStream:
    """`sys.stdout` or `sys.stderr` written per thread: an in-process job's thread writes to its
    log, every other thread (Snakemake's own console) to the stream this one replaced."""

    def __init__(self, stream: Any) -> None:
        self.console = stream

    def _target(self) -> Any:
        return getattr(_JOB_OUTPUT, "file", None) or self.console

    def write(self, text: str) -> int:
        return self._target().write(text)

    def flush(self) -> None:
        self._target().flush()

    def __getattr__(self, name: str) -> Any:
        return getattr(self._target(), name)


_JOB_OUTPUT = threading.local()
_INSTALL = threading.Lock()


def _console(stream: Any) -> Any:
    """The console behind `stream`, which may be a `_ThreadStream`."""
    return stream.console if isinstance(stream, _ThreadStream) else stream


@contextmanager
def job_output(log_path: Path, *, whole_process: bool) -> Iterator[None]:
    """Send what a job prints (a task's `print()`, Python's warnings) to its log, not to the
    console. A job in a process of its own redirects the process's `sys.stdout` and
    `sys.stderr`; a job in Snakemake's process only its own thread's (`_ThreadStream`), so that
    Snakemake's console and the other jobs' logs are untouched."""
    with open(log_path, "a", encoding="utf-8", buffering=1) as out:
        if whole_process:
            saved = sys.stdout, sys.stderr
            sys.stdout = sys.stderr = out
            try:
                yield
            finally:
                sys.stdout, sys.stderr = saved
            return
        with _INSTALL:
            for name in ("stdout", "stderr"):
                if not isinstance(getattr(sys, name), _ThreadStream):
                    setattr(sys, name, _ThreadStream(getattr(sys, name)))
        _JOB_OUTPUT.file = out
        try:
            yield
        finally:
            _JOB_OUTPUT.file = None


_RUNNING = 0  # jobs running in Snakemake's process now (`_in_process_job`)
_RUNNING_LOCK = threading.Lock()


@contextmanager
def _in_process_job(in_process: bool) -> Iterator[None]:
    """A job in Snakemake's process: counted while it runs, its memory released when it ends,
    failed or not (`release_memory`)."""
    global _RUNNING
    if not in_process:
        yield
        return
    with _RUNNING_LOCK:
        _RUNNING += 1
    try:
        yield
    finally:
        with _RUNNING_LOCK:
            _RUNNING -= 1
            alone = _RUNNING == 0
        release_memory(freeze=alone)


def release_memory(*, freeze: bool = False) -> None:
    """Hand the memory a finished job freed back to the system.

    Jobs in Snakemake's process free what they used, but glibc's allocator keeps freed heap
    pages for the process, so its resident memory would grow job after job (at N = 20,000,
    before this and the session's other memory changes, the report job alone took the process
    from 411 to 451 MB). `malloc_trim` returns them; where there is no glibc this does nothing.

    The collection first frees the job's reference cycles. A full one walks every object the
    process holds, Snakemake's DAG and every imported module: 0.15-0.35 s each time, the
    interpreter lock held, about 2 s of an N = 200 build. With `freeze` (no other job runs in
    the process) what survives is the process's own, modules and scheduler state, and is moved
    out of later collections (`gc.freeze`), which then walk only what was made since. Never
    while another job runs here: its cycles, frozen, would never be freed.
    """
    gc.collect()
    if freeze:
        gc.freeze()
    try:
        ctypes.CDLL("libc.so.6").malloc_trim(0)
    except (OSError, AttributeError):
        pass


@contextmanager
def job_log(log_path: Path) -> Iterator[None]:
    """Send this thread's `mjtrial` log records to the job's log file and to the console.

    Only the calling thread's records: jobs running side by side in Snakemake's process each
    keep their own log.
    """
    thread = threading.get_ident()
    console = logging.StreamHandler(_console(sys.stderr))
    handlers = [logging.FileHandler(log_path, mode="a"), console]
    for handler in handlers:
        handler.setFormatter(logging.Formatter("%(message)s"))
        handler.addFilter(lambda record: record.thread == thread)
        log.addHandler(handler)
    try:
        yield
    finally:
        for handler in handlers:
            log.removeHandler(handler)
            handler.close()


def run_in_process(
    script: str | Path,
    *,
    input: Any,
    output: Any,
    params: Any,
    wildcards: Any,
    threads: int,
    logs: Any,
    rule_name: str,
    config: Any = None,
) -> None:
    """Run a workflow script in Snakemake's own process, from a rule's `run:` block.

    The script gets a `snakemake` object with the job's input, output, params, wildcards,
    threads, log and rule name (and the config, where the rule gives it), as with `script:`.
    The script's code is compiled once per process.
    """
    job = SimpleNamespace(
        input=input,
        output=output,
        params=params,
        wildcards=wildcards,
        threads=threads,
        log=logs,
        rule=rule_name,
        config=config,
        in_process=True,
    )
    exec(_compiled(str(Path(script).resolve())), {"snakemake": job, "__name__": "mjtrial_job"})


# What the stages after the rollouts import (scipy.special is imported inside mjtrial.stats's
# functions, so that `mjtrial plan` starts fast). About 1.5 s of CPU; `import_late_stages`
# spends it while the rollouts run in their own processes, not on the run's critical path.
LATE_IMPORTS = (
    "mjtrial.stages.failures",
    "mjtrial.stages.analysis",
    "mjtrial.stages.manifest",
    "mjtrial.stages.report",
    "mjtrial.stages.seal",
    "scipy.special",
)


def import_in_background(modules: tuple[str, ...] = LATE_IMPORTS) -> threading.Thread:
    """Import `modules` in a daemon thread of this process (a job importing one of them at the
    same time waits for it, as with any import); an import error is left for the job to meet."""

    def load() -> None:
        for name in modules:
            try:
                importlib.import_module(name)
            except ImportError:
                pass

    thread = threading.Thread(target=load, name="mjtrial-imports", daemon=True)
    thread.start()
    return thread


_late_imports: list[threading.Thread] = []


def import_late_stages() -> None:
    """`import_in_background` of `LATE_IMPORTS`, once per process."""
    if not _late_imports:
        _late_imports.append(import_in_background())


@cache
def _compiled(path: str) -> CodeType:
    return compile(Path(path).read_text(encoding="utf-8"), path, "exec")


def resources_line() -> str:
    """This process's wall time since it started, CPU time and peak memory, as one log line.

    The figures the SLURM profile's `runtime` and `mem_mb` are declared from, and what the
    benchmark adds up per stage (`benchmarks/bench_vs_plain_loop.py`); they count the
    interpreter's start-up and imports too.
    """
    usage = resource.getrusage(resource.RUSAGE_SELF)
    return (
        f"# resources: wall {_process_age():.2f} s, "
        f"cpu {usage.ru_utime + usage.ru_stime:.2f} s, peak rss {_peak_rss_mb():.0f} MB"
    )


def cancel_scheduler_timers() -> None:
    """End the pending `threading.Timer`s of Snakemake's process, at the end of a run.

    Snakemake's scheduler starts one after each round (its job rate limit's re-evaluation,
    `--max-jobs-per-timespan`, 1 s by default); the interpreter waits for such a thread before
    it exits, so a finished run held its exit up to a second (benchmarks/profile_pipeline.py).
    Once the run is over nothing waits for them to fire.
    """
    for thread in threading.enumerate():
        if isinstance(thread, threading.Timer):
            thread.cancel()


def entered_line() -> str:
    """This process's wall and CPU time when its stage begins: its start and imports."""
    usage = resource.getrusage(resource.RUSAGE_SELF)
    return (
        f"# stage entered: wall {_process_age():.2f} s, cpu {usage.ru_utime + usage.ru_stime:.2f} s"
    )


def thread_resources_line(wall_start: float, cpu_start: float) -> str:
    """A job's own wall and CPU time when it ran in Snakemake's process (its thread's CPU; the
    process's memory is Snakemake's, so none is given)."""
    peak = _peak_rss_mb()
    return (
        f"# resources: wall {time.monotonic() - wall_start:.2f} s, "
        f"cpu {time.thread_time() - cpu_start:.2f} s, in snakemake's process "
        f"(rss {_rss_mb():.0f} MB, peak so far {peak:.0f} MB)"
    )


def _rss_mb() -> float:
    """This process's resident memory now, MB (0 where /proc is not there)."""
    try:
        with open("/proc/self/statm") as f:
            return int(f.read().split()[1]) * os.sysconf("SC_PAGE_SIZE") / 2**20
    except (OSError, ValueError, IndexError):
        return 0.0


def _peak_rss_mb() -> float:
    """This process's peak resident memory, MB: the kernel's `VmHWM`, not `ru_maxrss`, which
    keeps the peak of the process image before `exec` (a job process started by Snakemake
    would report Snakemake's own memory at the time, 329 MB for a rollout that used 240)."""
    try:
        with open("/proc/self/status") as f:
            for line in f:
                if line.startswith("VmHWM:"):
                    return int(line.split()[1]) / 1024
    except (OSError, ValueError, IndexError):
        pass
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024


def _process_age() -> float:
    """Seconds since this process started (from /proc; the time since import elsewhere)."""
    try:
        with open(f"/proc/{os.getpid()}/stat") as f:
            start_ticks = int(f.read().rpartition(")")[2].split()[19])
        with open("/proc/uptime") as f:
            uptime = float(f.read().split()[0])
        return uptime - start_ticks / os.sysconf("SC_CLK_TCK")
    except (OSError, ValueError, IndexError):
        return time.monotonic() - _IMPORTED


_IMPORTED = time.monotonic()
