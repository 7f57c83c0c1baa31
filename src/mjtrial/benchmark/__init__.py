"""The benchmark: tasks x methods x training seeds, tuned on development states."""

from collections.abc import Mapping
from typing import Any


def is_benchmark(config: Mapping[str, Any]) -> bool:
    """Whether a run's config is a benchmark's (it has a `benchmark` section). Here, not in
    `config`: every Snakemake start asks, and that module's imports (the tuning, CMA-ES) cost an
    experiment's start most of a second."""
    return "benchmark" in config
