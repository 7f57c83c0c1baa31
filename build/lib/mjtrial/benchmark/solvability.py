"""Is every randomized task still solvable? The corners of its state ranges (every parameter at
its low or high end: 2^d states), or a fixed Latin hypercube when there are too many
parameters for corners, run under the task's reference controller. A probe state the reference
fails is an unsolvable region of the randomization: it inflates the task's difficulty for every
method alike, and the report lists it before anyone reads the rates."""

from __future__ import annotations

import itertools
from collections.abc import Mapping, Sequence

import numpy as np
from scipy.stats import qmc


def probe_states(
    ranges: Mapping[str, Sequence[float]],
    parameters: Sequence[str],
    *,
    max_corner_parameters: int,
    n_hypercube: int,
    seed: int,
) -> tuple[str, dict[str, np.ndarray]]:
    """The probe states (parameter -> values, in `parameters` order) and how they were drawn
    (`"corners"` or `"latin hypercube"`)."""
    lows = np.array([ranges[p][0] for p in parameters], dtype=float)
    highs = np.array([ranges[p][1] for p in parameters], dtype=float)
    if len(parameters) <= max_corner_parameters:
        high = np.array(list(itertools.product((False, True), repeat=len(parameters))))
        values = np.where(high, highs, lows)  # the ends exactly, not low + 1.0 * (high - low)
        how = "corners"
    else:
        unit = qmc.LatinHypercube(d=len(parameters), rng=np.random.default_rng(seed)).random(
            n_hypercube
        )
        values = lows + unit * (highs - lows)
        how = "latin hypercube"
    return how, {p: values[:, i] for i, p in enumerate(parameters)}
