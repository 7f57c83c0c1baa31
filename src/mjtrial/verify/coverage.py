"""How many episodes verify re-simulates: every one when that fits a time budget, else a
sample per shard, and the words that say which.

A sample of 20 per shard misses a forged row more often than not at N = 200, and the N = 200
experiments re-simulate whole in seconds (the two built-in ones: 0.02-0.03 s of CPU per
episode, alone). So verify times a few episodes of the first condition and re-simulates
every one when the estimate for all is within `RESIMULATE_BUDGET_S`; a larger run gets
`DEFAULT_RESIMULATE` per shard, and the check line says how many of how many it covered.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass

__all__ = ["DEFAULT_RESIMULATE", "RESIMULATE_ALL", "RESIMULATE_BUDGET_S", "Coverage", "coverage"]

# Episodes re-simulated per shard when every one would not fit the budget: at 100,000 states
# (200 shards) about a minute.
DEFAULT_RESIMULATE = 20
# CPU seconds of re-simulation within which verify re-simulates every episode.
RESIMULATE_BUDGET_S = 60.0
# `--resimulate all`: more than any shard holds.
RESIMULATE_ALL = 2**62
_TIMED = 5  # episodes timed for the estimate


@dataclass(frozen=True)
class Coverage:
    """Episodes re-simulated per shard, and why that many (for the check line)."""

    per_shard: int
    why: str


def _cpu_seconds(resimulate: Callable[[Sequence[int]], object], ids: Sequence[int]) -> float:
    start = time.process_time()
    resimulate(ids)
    return time.process_time() - start


def coverage(
    episodes: int,
    timed_ids: Sequence[int],
    resimulate: Callable[[Sequence[int]], object],
    *,
    budget_s: float = RESIMULATE_BUDGET_S,
) -> Coverage:
    """Every episode (`RESIMULATE_ALL`) when `episodes` of them are estimated to take at most
    `budget_s` of CPU, else `DEFAULT_RESIMULATE` per shard. The estimate times `resimulate` on
    one of `timed_ids` and, unless that one call (the model and task loaded with the episode)
    already bounds every episode within the budget, on up to 5: the difference is the
    episodes' cost without the loading (which verify pays once per shard): a small run is
    timed on one episode, not six."""
    ids = list(timed_ids)[:_TIMED]
    if not ids or episodes <= 0:
        return Coverage(RESIMULATE_ALL, "every episode")
    one = _cpu_seconds(resimulate, ids[:1])
    if one * episodes <= budget_s:
        per_episode = one  # an upper bound: it includes the loading
    elif len(ids) > 1:
        per_episode = max(_cpu_seconds(resimulate, ids) - one, 0.0) / (len(ids) - 1)
    else:
        per_episode = one
    estimate = per_episode * episodes
    if estimate <= budget_s:
        return Coverage(RESIMULATE_ALL, f"every episode, about {estimate:.0f} s")
    return Coverage(
        DEFAULT_RESIMULATE,
        f"{DEFAULT_RESIMULATE} per shard: every one would take about {estimate:.0f} s, over "
        f"the {budget_s:.0f} s budget; --resimulate all re-simulates them all",
    )
