"""The timing both closed-loop speed benchmarks share: a plain per-episode loop against the
engine on 1 and 2 threads, alternating which runs first in each repeat (a shared, noisy machine
drifts), and the medians of the paired ratios."""

from __future__ import annotations

import statistics
import time
from collections.abc import Callable
from typing import Any

THREADS = (1, 2)


def time_alternating(
    loop: Callable[[], Any], engine: Callable[[int], Any], repeats: int
) -> tuple[dict[str, Any], dict[str, list[float]], dict[int, list[float]]]:
    """Run `loop()` and `engine(threads)` for each of `THREADS`, `repeats` times, alternating
    their order. Returns the last outcome of each (`loop`, `engine`), the seconds of each run
    (`loop`, and the engine's by thread count as `"1"`, `"2"`) and the paired ratios
    loop / engine by thread count."""
    seconds: dict[str, list[float]] = {"loop": [], **{str(t): [] for t in THREADS}}
    ratios: dict[int, list[float]] = {t: [] for t in THREADS}
    outcome: dict[str, Any] = {}
    for repeat in range(repeats):
        for threads in THREADS:
            runs = {"loop": loop, "engine": lambda t=threads: engine(t)}
            order = ["loop", "engine"] if repeat % 2 == 0 else ["engine", "loop"]
            spent = {}
            for name in order:
                t0 = time.perf_counter()
                outcome[name] = runs[name]()
                spent[name] = time.perf_counter() - t0
            seconds["loop"].append(spent["loop"])
            seconds[str(threads)].append(spent["engine"])
            ratios[threads].append(spent["loop"] / spent["engine"])
    return outcome, seconds, ratios


def print_rates(n: int, seconds: dict[str, list[float]], ratios: dict[int, list[float]]) -> None:
    """Episodes per second of the loop and the engine, and the engine's median ratio (range)."""
    print(f"plain per-episode loop:   {n / statistics.median(seconds['loop']):8.0f} episodes/s")
    for threads in THREADS:
        r = ratios[threads]
        print(
            f"engine, {threads} thread{'s' if threads > 1 else ' '}:         "
            f"{n / statistics.median(seconds[str(threads)]):8.0f} episodes/s   "
            f"{statistics.median(r):.2f}x the loop ({min(r):.2f}-{max(r):.2f})"
        )
