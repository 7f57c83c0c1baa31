"""The tests' job server (tests/forked_jobs.py) runs a script as `python script.py` would: its
output, its exit status, its folder and environment; a job whose environment differs in what an
interpreter reads at start is a fresh process; a killed launcher takes its job with it."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import forked_jobs
import pytest


@pytest.fixture(scope="module")
def address():
    return forked_jobs.start()


def launch(address: str, script: Path, env: dict | None = None, **kwargs):
    environment = os.environ | {name: "1" for name in forked_jobs.THREAD_VARIABLES}
    environment |= {forked_jobs.ADDRESS: address, **(env or {})}
    return subprocess.run(
        [sys.executable, "-S", "-I", str(forked_jobs.LAUNCHER), str(script)],
        capture_output=True,
        text=True,
        env=environment,
        timeout=60,
        **kwargs,
    )


def test_output_status_folder_and_environment_are_the_scripts(address, tmp_path):
    script = tmp_path / "job.py"
    script.write_text(
        "import os, sys\n"
        "print('out', os.getcwd(), os.environ['WHO'], sys.argv[0] == __file__, __name__)\n"
        "print('err', file=sys.stderr)\n"
        "print('forked' if 'mujoco' in sys.modules else 'fresh')\n"
        "sys.exit(3)\n"
    )
    done = launch(address, script, env={"WHO": "me"}, cwd=tmp_path)
    assert done.returncode == 3
    assert done.stdout.splitlines() == [f"out {tmp_path} me True __main__", "forked"]
    assert done.stderr == "err\n"


def test_an_exception_is_status_1_with_its_traceback(address, tmp_path):
    script = tmp_path / "job.py"
    script.write_text("raise ValueError('no good')\n")
    done = launch(address, script)
    assert done.returncode == 1
    assert "ValueError: no good" in done.stderr and "Traceback" in done.stderr


def test_another_interpreter_setting_starts_a_fresh_process(address, tmp_path):
    script = tmp_path / "job.py"
    script.write_text("import sys\nprint('forked' if 'mujoco' in sys.modules else 'fresh')\n")
    assert launch(address, script).stdout == "forked\n"
    assert launch(address, script, env={"OMP_NUM_THREADS": "2"}).stdout == "fresh\n"
    assert launch(address, script, env={"PYTHONHASHSEED": "7"}).stdout == "fresh\n"


def test_a_killed_launcher_kills_its_job(address, tmp_path):
    script = tmp_path / "job.py"
    pid_file = tmp_path / "pid"
    script.write_text(
        f"import os, time\nopen({str(pid_file)!r}, 'w').write(str(os.getpid()))\ntime.sleep(120)\n"
    )
    environment = os.environ | {name: "1" for name in forked_jobs.THREAD_VARIABLES}
    launcher = subprocess.Popen(
        [sys.executable, "-S", "-I", str(forked_jobs.LAUNCHER), str(script)],
        env=environment | {forked_jobs.ADDRESS: address},
    )
    deadline = time.monotonic() + 30
    while not (pid_file.exists() and pid_file.read_text()) and time.monotonic() < deadline:
        time.sleep(0.05)
    job = int(pid_file.read_text())
    os.kill(launcher.pid, signal.SIGKILL)
    launcher.wait()
    deadline = time.monotonic() + 10
    while Path(f"/proc/{job}").exists() and time.monotonic() < deadline:
        time.sleep(0.05)
    assert not Path(f"/proc/{job}").exists()
