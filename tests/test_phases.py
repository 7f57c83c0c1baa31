"""The rollout job's phase clock (mjtrial.sim.phases) and the end of a run's scheduler timers."""

from __future__ import annotations

import threading
import time

from mjtrial.sim import phases
from mjtrial.workflow_script import cancel_scheduler_timers


def test_a_nested_phase_pauses_the_outer_one():
    with phases.clocked() as clock:
        with phases.phase("outer"):
            time.sleep(0.05)
            with phases.phase("inner"):
                time.sleep(0.1)
            time.sleep(0.05)
        phases.add("other thread", 2.0, 1.5)
    outer, inner = clock.totals["outer"], clock.totals["inner"]
    assert 0.1 <= outer[0] < 0.15  # the two 50 ms sleeps, not the inner 100 ms
    assert 0.1 <= inner[0] < 0.15
    assert outer[1] < 0.05 and inner[1] < 0.05  # sleeping costs no CPU
    assert clock.totals["other thread"] == [2.0, 1.5]
    line = clock.line()
    assert line.startswith("# phases: outer ") and "other thread 2.000 s (cpu 1.500 s)" in line


def test_no_clock_no_charge():
    with phases.phase("physics"):
        pass
    phases.add("x", 1.0, 1.0)  # nothing active: nothing to charge, no error
    with phases.clocked() as clock:
        pass
    assert clock.totals == {}


def test_pending_timers_end_without_firing():
    fired = []
    timer = threading.Timer(30, lambda: fired.append(True))
    timer.start()
    cancel_scheduler_timers()
    timer.join(timeout=2)
    assert not timer.is_alive() and not fired


def _spin(seconds: float) -> None:
    end = time.thread_time() + seconds
    while time.thread_time() < end:
        pass


def test_a_phase_of_every_thread_counts_the_cpu_of_a_worker_it_waits_for():
    with phases.clocked() as clock:
        for name, every in (("own thread", False), ("every thread", True)):
            with phases.phase(name, every_thread=every):
                worker = threading.Thread(target=_spin, args=(0.2,))
                worker.start()
                worker.join()
    assert clock.totals["own thread"][1] < 0.05  # the caller only waited
    assert clock.totals["every thread"][1] >= 0.19  # the worker's 0.2 s of CPU
