"""Where a rollout job's time goes, by phase (physics, recording, measures, stamping, writing):
a light clock the rollout stage starts and the engine and recording writer charge, logged as one
`# phases:` line at the job's end and read by `benchmarks/profile_pipeline.py`.

Each phase's time is exclusive (a phase entered inside another pauses it): wall
(`time.perf_counter`) and CPU, the calling thread's (`time.thread_time`) or, for a phase whose
work runs on other threads (`mujoco.rollout`'s pool), every thread's (`time.process_time`, the
recording writer's overlap included). A few clock reads per batch: nothing against the
batch's physics.
"""

from __future__ import annotations

import time
from collections.abc import Iterator
from contextlib import contextmanager

PHASES_PREFIX = "# phases:"


class PhaseClock:
    """Accumulated (wall s, CPU s) per phase name, exclusive of nested phases."""

    def __init__(self) -> None:
        self.totals: dict[str, list[float]] = {}
        self._current: str | None = None
        self._every_thread = False
        self._since = (0.0, 0.0, 0.0)

    def add(self, name: str, wall: float, cpu: float) -> None:
        total = self.totals.setdefault(name, [0.0, 0.0])
        total[0] += wall
        total[1] += cpu

    def _charge(self) -> None:
        now = time.perf_counter(), time.thread_time(), time.process_time()
        if self._current is not None:
            cpu = 2 if self._every_thread else 1
            self.add(self._current, now[0] - self._since[0], now[cpu] - self._since[cpu])
        self._since = now

    @contextmanager
    def phase(self, name: str, *, every_thread: bool = False) -> Iterator[None]:
        self._charge()
        outer = self._current, self._every_thread
        self._current, self._every_thread = name, every_thread
        try:
            yield
        finally:
            self._charge()
            self._current, self._every_thread = outer

    def line(self) -> str:
        """One log line: `# phases: <name> <wall> s (cpu <cpu> s), ...`."""
        parts = [f"{n} {w:.3f} s (cpu {c:.3f} s)" for n, (w, c) in self.totals.items()]
        return f"{PHASES_PREFIX} {', '.join(parts)}"


_active: PhaseClock | None = None


@contextmanager
def clocked() -> Iterator[PhaseClock]:
    """Make a fresh clock the one `phase` and `add` charge, for the block."""
    global _active
    outer, _active = _active, PhaseClock()
    try:
        yield _active
    finally:
        _active = outer


@contextmanager
def phase(name: str, *, every_thread: bool = False) -> Iterator[None]:
    """Charge the block to phase `name` of the active clock (nothing when none is); its CPU
    is every thread's with `every_thread`."""
    if _active is None:
        yield
        return
    with _active.phase(name, every_thread=every_thread):
        yield


def add(name: str, wall: float, cpu: float) -> None:
    """Add a measured span (e.g. another thread's) to the active clock's phase `name`."""
    if _active is not None:
        _active.add(name, wall, cpu)
