"""The solvability check's probe states (mjtrial.benchmark.solvability): every corner of the
ranges exactly, or a Latin hypercube (one state in each of n equal bins of every parameter)."""

from __future__ import annotations

import itertools

import numpy as np

from mjtrial.benchmark.solvability import probe_states

RANGES = {"a": [-1.0, 2.0], "b": [0.1, 0.3], "c": [5.0, 6.0], "d": [-0.5, 0.5]}


def test_up_to_the_limit_every_corner_once_and_exactly():
    how, values = probe_states(
        RANGES, list(RANGES), max_corner_parameters=4, n_hypercube=10, seed=0
    )
    assert how == "corners"
    got = set(zip(*(values[p] for p in RANGES), strict=True))
    assert got == set(itertools.product(*(RANGES[p] for p in RANGES)))
    assert len(values["a"]) == 16


def test_beyond_the_limit_a_seeded_latin_hypercube_within_the_ranges():
    n = 12
    how, values = probe_states(RANGES, list(RANGES), max_corner_parameters=3, n_hypercube=n, seed=5)
    assert how == "latin hypercube"
    for p, (low, high) in RANGES.items():
        v = values[p]
        assert v.shape == (n,) and np.all((v >= low) & (v <= high))
        bins = np.floor((v - low) / (high - low) * n).astype(int)
        assert sorted(bins) == list(range(n))  # one state in each of the n bins
    _, again = probe_states(RANGES, list(RANGES), max_corner_parameters=3, n_hypercube=n, seed=5)
    _, other = probe_states(RANGES, list(RANGES), max_corner_parameters=3, n_hypercube=n, seed=6)
    assert all(np.array_equal(values[p], again[p]) for p in RANGES)
    assert not np.array_equal(values["a"], other["a"])
