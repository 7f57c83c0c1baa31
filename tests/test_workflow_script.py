"""Jobs run by `mjtrial.workflow_script`: in Snakemake's process (a thread each) or their own.

The stage functions here are stand-ins defined in a script file; what is checked is the job's
log (stamp first, its own messages only, resources last), its one-line error, and how a failure
ends the job in each mode.
"""

from __future__ import annotations

import json
import logging
import subprocess
import sys
import threading
from pathlib import Path

import pytest
from conftest import REPO_ROOT
from snakemake.iocontainers import Namedlist

from mjtrial.provenance import STAMP_VERSION
from mjtrial.task import load_task
from mjtrial.workflow_script import JobFailed, failure_reasons, job_log, run_in_process

pytestmark = pytest.mark.end_to_end

SCRIPT = """
import logging
import sys
import warnings
from mjtrial.workflow_script import run_job

snakemake = globals()["snakemake"]
log = logging.getLogger("mjtrial")


def stage(*, what, output):
    if what == "fail":
        raise ValueError("the states table has\\n no rows")
    if what == "print":  # a task that prints and warns
        print("the task prints")
        print("the task prints to stderr", file=sys.stderr)
        warnings.warn("the task warns")
        snakemake.params.get("during", lambda: None)()
    log.info("%s wrote %s", what, output)
    with open(output, "w") as f:
        f.write(snakemake.rule)


run_job(snakemake, stage, rule="states", what=snakemake.params.what, output=snakemake.output[0])
"""


def Named(*values, **named):
    """A Snakemake named list (as a job's input, output, params and log are)."""
    nl = Namedlist(toclone=list(values)) if values else Namedlist()
    for key, value in named.items():
        nl.append(value)
        nl._add_name(key)
    return nl


def job_args(tmp_path: Path, what: str, name: str = "job") -> dict:
    return dict(
        input=Named(),
        output=Named(str(tmp_path / f"{name}.txt")),
        params=Named(what=what, slice={"n": 3}),
        wildcards=Named(),
        threads=1,
        logs=Named(str(tmp_path / "logs" / f"{name}.log")),
        rule_name="states",
    )


@pytest.fixture
def script(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)  # the stamp's repository root: not a git repository here
    path = tmp_path / "stage_script.py"
    path.write_text(SCRIPT)
    return path


def stamp_of(log_text: str) -> dict:
    first = log_text.splitlines()[0]
    assert first.startswith("# mjtrial.provenance: ")
    return json.loads(first.removeprefix("# mjtrial.provenance: "))


def test_in_process_job_writes_stamp_messages_and_resources(script, tmp_path):
    run_in_process(script, **job_args(tmp_path, "states"))
    assert (tmp_path / "job.txt").read_text() == "states"  # the script saw snakemake.rule
    lines = (tmp_path / "logs/job.log").read_text().splitlines()
    stamp = stamp_of(lines[0])
    assert stamp["mjtrial_stamp"] == STAMP_VERSION
    assert stamp["rule"] == "states" and stamp["config_slice"] == {"n": 3}
    assert lines[1] == f"states wrote {tmp_path / 'job.txt'}"
    assert lines[2].startswith("# resources: wall ") and "in snakemake's process" in lines[2]
    assert len(lines) == 3


def test_in_process_failure_raises_with_one_line_and_traceback_in_log(script, tmp_path, capsys):
    with pytest.raises(JobFailed) as failed:
        run_in_process(script, **job_args(tmp_path, "fail"))
    assert str(failed.value).startswith("states: the states table has no rows (traceback in ")
    err = capsys.readouterr().err
    assert "error: states: the states table has no rows\n" in err
    assert "Traceback" not in err  # the console gets one line; the log the traceback
    log_text = (tmp_path / "logs/job.log").read_text()
    stamp_of(log_text)
    assert "\nerror: states: the states table has no rows\n" in log_text
    assert "Traceback (most recent call last)" in log_text
    assert 'raise ValueError("the states table has' in log_text
    assert "# resources" not in log_text
    assert not (tmp_path / "job.txt").exists()
    # the handlers are gone: a later message reaches no job's log
    logging.getLogger("mjtrial").info("after the job")
    assert "after the job" not in (tmp_path / "logs/job.log").read_text()


def _run_as_script(script, tmp_path, what: str):
    """The job run as Snakemake's `script:` runs it: a process of its own (its args, the
    finished process)."""
    args = job_args(tmp_path, what)
    runner = tmp_path / "runner.py"
    runner.write_text(
        "import sys\n"
        f"sys.path.insert(0, {str(Path(__file__).parent)!r})\n"
        "from test_workflow_script import Named\n"
        "from types import SimpleNamespace\n"
        f"snakemake = SimpleNamespace(input=Named(), output=Named({args['output'][0]!r}),\n"
        f"    params=Named(what={what!r}, slice={{}}), log=Named(" + repr(args["logs"][0]) + "),\n"
        "    rule='states')\n"
        f"exec(open({str(script)!r}).read(), {{'snakemake': snakemake}})\n"
    )
    return args, subprocess.run([sys.executable, str(runner)], capture_output=True, text=True)


def test_script_process_failure_exits_1_with_one_line(script, tmp_path):
    """As Snakemake's `script:` runs it: a process of its own, exit status 1."""
    args, proc = _run_as_script(script, tmp_path, "fail")
    assert proc.returncode == 1, proc.stderr
    assert proc.stderr == "error: states: the states table has no rows\n"


@pytest.mark.filterwarnings("ignore:the task warns")
def test_an_in_process_jobs_prints_go_to_its_log_and_the_console_stays(script, tmp_path, capsys):
    """The job's thread prints into its log; Snakemake's threads still print to the console."""
    job_running, console_printed = threading.Event(), threading.Event()

    def during():  # the job is running: another thread (Snakemake's) prints meanwhile
        job_running.set()
        assert console_printed.wait(10)

    def snakemake_console():
        assert job_running.wait(10)
        print("snakemake prints")
        print("snakemake warns", file=sys.stderr)
        console_printed.set()

    other = threading.Thread(target=snakemake_console)
    other.start()
    args = job_args(tmp_path, "print")
    args["params"] = Named(what="print", slice={}, during=during)
    run_in_process(script, **args)
    other.join()
    console = capsys.readouterr()
    assert "snakemake prints" in console.out and "snakemake warns" in console.err
    assert "the task" not in console.out + console.err
    log_text = (tmp_path / "logs/job.log").read_text()
    assert "\nthe task prints\nthe task prints to stderr\n" in log_text
    assert "snakemake prints" not in log_text and "snakemake warns" not in log_text
    print("after the job")  # the thread's redirection ended with the job
    assert "after the job" in capsys.readouterr().out


def test_a_process_job_leaves_nothing_for_the_exits_collections(script, tmp_path):
    """A job in a process of its own freezes what is left once it has succeeded, so that the
    interpreter's exit does not walk it (not a failed one: its exit is not timed)."""
    marker = tmp_path / "frozen.txt"
    script.write_text(
        "import atexit, gc\n"
        f"atexit.register(lambda: open({str(marker)!r}, 'w').write(str(gc.get_freeze_count())))\n"
        + SCRIPT
    )
    args, proc = _run_as_script(script, tmp_path, "write")
    assert proc.returncode == 0, proc.stderr
    assert Path(args["output"][0]).read_text() == "states"
    assert int(marker.read_text()) > 1000  # every module's objects, frozen


def test_a_process_jobs_prints_and_warnings_go_to_its_log(script, tmp_path):
    """As Snakemake's `script:` runs it: what the task prints or warns is in the job's log."""
    args, proc = _run_as_script(script, tmp_path, "print")
    assert proc.returncode == 0, proc.stderr
    assert proc.stdout == ""
    assert "the task" not in proc.stderr
    log_text = Path(args["logs"][0]).read_text()
    assert "\nthe task prints\nthe task prints to stderr\n" in log_text
    assert "UserWarning: the task warns" in log_text


def test_job_log_keeps_each_threads_messages_apart(tmp_path):
    """Two jobs side by side in one process: each log holds its own thread's messages only."""
    log = logging.getLogger("mjtrial")
    ready = threading.Barrier(2)

    def job(name: str) -> None:
        path = tmp_path / f"{name}.log"
        path.write_text("")
        with job_log(path):
            ready.wait()
            for i in range(50):
                log.info("%s %d", name, i)
            ready.wait()

    threads = [threading.Thread(target=job, args=(n,)) for n in ("a", "b")]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    for name in ("a", "b"):
        lines = (tmp_path / f"{name}.log").read_text().splitlines()
        assert lines == [f"{name} {i}" for i in range(50)]
    assert not [h for h in log.handlers if isinstance(h, logging.FileHandler)]


def test_a_task_package_loads_while_another_thread_imports():
    """Snakemake's process imports the late stages in a thread (`import_in_background`) while an
    in-process job loads a task package; the loader must not iterate `sys.modules` as it grows."""
    stop = threading.Event()

    def churn() -> None:  # what an import does to sys.modules, as often as possible
        i = 0
        while not stop.is_set():
            sys.modules[f"_mjtrial_churn_{i % 64}"] = sys
            sys.modules.pop(f"_mjtrial_churn_{(i + 32) % 64}", None)
            i += 1

    interval = sys.getswitchinterval()
    sys.setswitchinterval(1e-6)  # a thread switch at almost every bytecode
    thread = threading.Thread(target=churn, daemon=True)
    thread.start()
    try:
        for _ in range(50):
            load_task(REPO_ROOT / "tasks" / "gantry_lift" / "task.py")
    finally:
        stop.set()
        thread.join()
        sys.setswitchinterval(interval)
        for i in range(64):
            sys.modules.pop(f"_mjtrial_churn_{i}", None)


def test_a_failed_jobs_reason_is_read_back_from_its_log_for_the_console(script, tmp_path):
    """`onerror` repeats each failed job's one-line reason at the end of the console: the line
    `run_job` wrote (not the traceback below it); a job killed before writing one is said to
    have stopped without saying why, with its log's last line; a log never written is named."""
    args, proc = _run_as_script(script, tmp_path, "fail")
    assert proc.returncode == 1
    failed = args["logs"][0]
    killed = tmp_path / "logs" / "rollout_slow_00001.log"
    killed.write_text("# mjtrial.provenance: {}\nrollout:slow#00001: 3/5 episodes\n")
    never = tmp_path / "logs" / "rollout_slow_00002.log"
    assert failure_reasons([failed, killed, never]) == [
        f"error: states: the states table has no rows (its log: {failed})",
        "error: a job stopped without saying why (killed, out of memory or crashed); its log "
        f"{killed} ends: rollout:slow#00001: 3/5 episodes",
        f"error: a job failed before writing its log {never}",
    ]
    assert failure_reasons([failed] * 3) == failure_reasons([failed])  # each log once
    many = failure_reasons([killed, failed, never], shown=1)
    assert many[1:] == ["error: and 2 more failed jobs: see their logs"]


class _Cycle:
    """An object in a reference cycle: only the collector frees it."""

    def __init__(self) -> None:
        self.me = self


def test_a_job_alone_freezes_what_survives_and_a_job_beside_another_never_does(script, tmp_path):
    """`release_memory` after an in-process job: the job's own cycles are freed; when no other
    job runs there, what survives is frozen out of later collections (each then walks only the
    new objects); a job that ends while another runs freezes nothing, or the other's cycles
    would never be freed."""
    import gc
    import weakref

    gc.unfreeze()
    try:
        made: dict[str, weakref.ref] = {}

        def inner_job():  # runs while the outer job is still running
            cycle = _Cycle()
            made["during outer"] = weakref.ref(cycle)
            del cycle
            frozen = gc.get_freeze_count()
            run_in_process(script, **job_args(tmp_path, "states", name="inner"))
            made["freeze count unchanged"] = gc.get_freeze_count() == frozen
            assert made["during outer"]() is None  # the inner job's collection freed it

        outer = job_args(tmp_path, "print", name="outer")
        outer["params"] = Named(what="print", slice={}, during=inner_job)
        assert gc.get_freeze_count() == 0
        run_in_process(script, **outer)
        assert made["freeze count unchanged"]  # the inner job ended beside the outer one
        assert gc.get_freeze_count() > 0  # the outer job ended alone
        cycle = _Cycle()
        gone = weakref.ref(cycle)
        del cycle
        run_in_process(script, **job_args(tmp_path, "states", name="after"))
        assert gone() is None  # made after the freeze: still collected
    finally:
        gc.unfreeze()
