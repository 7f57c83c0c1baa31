"""Statistics for a paired binary-outcome experiment.

The experiment runs the same initial states under two conditions and records success or
failure of an episode for each, so the natural data are two aligned 0/1 arrays of shape
``(n_pairs,)``. This module provides the interval estimates, the paired test and the sample-size
calculations used to plan and report such an experiment.

Everything here is pure: no I/O, no global state, and randomness only through
``np.random.default_rng(seed)`` so that every interval is reproducible from its seed. The Wilson
interval is Newcombe's formula as ``scipy.stats.binomtest`` computes it, and the exact McNemar
p-value the binomial CDF from ``scipy.special.betainc`` (both tested against ``binomtest``;
importing scipy.stats would cost Snakemake's process a second and 74 MB); the percentile
bootstrap is written out here because its documented draws define the published intervals.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from numbers import Integral, Real
from statistics import NormalDist
from typing import Any, overload

import numpy as np

__all__ = [
    "BOOTSTRAP_METHOD",
    "HOLM_METHOD",
    "MCNEMAR_METHOD",
    "NEWCOMBE_METHOD",
    "McNemarResult",
    "bootstrap_ci",
    "episodes_for_halfwidth",
    "holm",
    "iqm",
    "iqm_ci",
    "mcnemar",
    "mcnemar_pairs_needed",
    "newcombe_paired_interval",
    "paired_difference_ci",
    "wilson_interval",
]

BOOTSTRAP_METHOD = "percentile bootstrap"
"""Name of the interval method used by :func:`bootstrap_ci` and the functions built on it."""

MCNEMAR_METHOD = "exact McNemar (two-sided binomial)"
"""Name of the test performed by :func:`mcnemar`."""

NEWCOMBE_METHOD = "Newcombe hybrid score (1998, method 10, with the phi correction)"
"""Name of the interval computed by :func:`newcombe_paired_interval`."""

HOLM_METHOD = "Holm step-down (family-wise error rate)"
"""Name of the multiplicity correction performed by :func:`holm`."""

# Upper bound on the number of elements in one block of bootstrap resamples (index array and
# gathered values each hold this many elements), so memory stays bounded (~16 MB) for large n.
_MAX_BLOCK_ELEMENTS = 1 << 20

# Relative tolerance under which a computed sample size is treated as the integer it is
# mathematically equal to, so floating-point noise cannot bump e.g. 100.00000000000001 to 101.
_INTEGER_RTOL = 1e-9


# --------------------------------------------------------------------------------------------
# Validation helpers
# --------------------------------------------------------------------------------------------


def _check_int(name: str, value: Any, *, minimum: int | None = None) -> int:
    if isinstance(value, bool) or not isinstance(value, Integral):
        raise ValueError(f"{name} must be an integer, got {value!r}")
    value = int(value)
    if minimum is not None and value < minimum:
        raise ValueError(f"{name} must be >= {minimum}, got {value}")
    return value


def _check_real(name: str, value: Any) -> float:
    if isinstance(value, bool) or not isinstance(value, Real):
        raise ValueError(f"{name} must be a real number, got {value!r}")
    value = float(value)
    if not math.isfinite(value):
        raise ValueError(f"{name} must be finite, got {value}")
    return value


def _check_open_unit(name: str, value: Any) -> float:
    value = _check_real(name, value)
    if not 0.0 < value < 1.0:
        raise ValueError(f"{name} must be strictly between 0 and 1, got {value}")
    return value


def _as_1d_float(name: str, values: Any) -> np.ndarray:
    try:
        arr = np.asarray(values, dtype=float)
    except (TypeError, ValueError) as exc:
        raise ValueError(f"{name} must be an array of real numbers: {exc}") from None
    if arr.ndim != 1:
        raise ValueError(f"{name} must be one-dimensional, got shape {arr.shape}")
    if arr.size == 0:
        raise ValueError(f"{name} must contain at least one value")
    if not np.all(np.isfinite(arr)):
        raise ValueError(f"{name} must contain only finite values")
    return arr


def _as_binary(name: str, values: Any) -> np.ndarray:
    arr = np.asarray(values)
    if arr.ndim != 1:
        raise ValueError(f"{name} must be one-dimensional, got shape {arr.shape}")
    if arr.size == 0:
        raise ValueError(f"{name} must contain at least one value")
    if arr.dtype == bool:
        return arr
    if arr.dtype.kind not in "iuf":
        raise ValueError(f"{name} must hold 0/1 or bool outcomes, got dtype {arr.dtype}")
    is_one = arr == 1
    if not np.all(is_one | (arr == 0)):
        raise ValueError(f"{name} must hold only 0/1 or bool outcomes")
    return is_one


def _z_two_sided(confidence: float) -> float:
    """Standard normal quantile z with P(|Z| <= z) = confidence."""
    return NormalDist().inv_cdf(0.5 + confidence / 2.0)


def _ceil_count(x: float) -> int:
    """Ceiling of a positive sample size, robust to floating-point noise; at least 1."""
    nearest = round(x)
    if abs(x - nearest) <= _INTEGER_RTOL * max(1.0, abs(x)):
        return max(1, int(nearest))
    return max(1, math.ceil(x))


# --------------------------------------------------------------------------------------------
# Intervals
# --------------------------------------------------------------------------------------------


def wilson_interval(successes: int, n: int, confidence: float = 0.95) -> tuple[float, float]:
    """Wilson score interval for a binomial proportion.

    Preferred over the Wald interval because it keeps sensible coverage near 0 and 1, where
    success rates often sit.

    Args:
        successes: Number of successes, ``0 <= successes <= n``.
        n: Number of trials, ``>= 1``.
        confidence: Two-sided confidence level in (0, 1).

    Returns:
        ``(low, high)`` within [0, 1]; ``low`` is exactly 0 when ``successes == 0`` and ``high``
        exactly 1 when ``successes == n``.
    """
    n = _check_int("n", n, minimum=1)
    successes = _check_int("successes", successes, minimum=0)
    if successes > n:
        raise ValueError(f"successes must be <= n ({n}), got {successes}")
    confidence = _check_open_unit("confidence", confidence)
    # Newcombe's (1998) formula, written as scipy.stats.binomtest(...).proportion_ci(
    # method="wilson") computes it (the same floats; tested against it): scipy.stats costs a
    # second and 74 MB to import in Snakemake's process, scipy.special 0.3 s and 27 MB. Imported
    # here so that the CLI's sample-size commands, which never need it, start fast.
    from scipy.special import ndtri

    z = ndtri(0.5 + 0.5 * confidence)
    p = successes / n
    denom = 2 * (n + z**2)
    center = (2 * n * p + z**2) / denom
    delta = z / denom * math.sqrt(4 * n * p * (1 - p) + z**2)
    low = 0.0 if successes == 0 else center - delta
    high = 1.0 if successes == n else center + delta
    return float(low), float(high)


def _accepts_axis(statistic: Callable[..., Any], values: np.ndarray) -> bool:
    """Whether ``statistic(x, axis=-1)`` reduces each row of a 2-D array to one number."""
    try:
        probe = statistic(values[np.newaxis, :], axis=-1)
    except TypeError:
        return False
    if np.shape(probe) != (1,):
        raise ValueError(
            "statistic must reduce along axis=-1 to one value per resample when it accepts "
            f"an axis keyword; got shape {np.shape(probe)} for input shape (1, {values.size})"
        )
    return True


def _scalar(name: str, value: Any) -> float:
    arr = np.asarray(value)
    if arr.size != 1:
        raise ValueError(f"{name} must return a scalar, got shape {arr.shape}")
    return float(arr.reshape(()))


def bootstrap_ci(
    values: Any,
    statistic: Callable[..., Any] = np.mean,
    *,
    n_resamples: int,
    confidence: float,
    seed: int,
) -> tuple[float, float, float]:
    """Percentile bootstrap confidence interval for a statistic of one sample.

    Makes no distributional assumption, which suits bounded or skewed per-episode metrics.

    Resample indices are drawn as ``rng.integers(0, n, size=(n_resamples, n))`` with
    ``rng = np.random.default_rng(seed)``, generated in row blocks to bound memory; the result
    does not depend on the block size. The statistic is applied to each resample row: it should
    accept an ``axis`` keyword and reduce along ``axis=-1`` (as ``np.mean``, ``np.median`` and
    :func:`iqm` do) so that whole blocks are evaluated at once. A statistic that raises
    ``TypeError`` for the ``axis`` keyword is instead called once per resample (slower, same
    result).

    Args:
        values: Sample, shape ``(n,)`` with ``n >= 1``, finite real values (bool allowed).
        statistic: Reduction of a sample to a scalar, ideally accepting ``axis=-1``.
        n_resamples: Number of bootstrap resamples, ``>= 1``.
        confidence: Two-sided confidence level in (0, 1).
        seed: Non-negative seed for ``np.random.default_rng``.

    Returns:
        ``(estimate, low, high)`` where ``estimate = statistic(values)`` and ``low``/``high``
        are the ``(1 - confidence) / 2`` and ``(1 + confidence) / 2`` quantiles (numpy's
        default linear interpolation) of the bootstrap distribution.
    """
    arr = _as_1d_float("values", values)
    if not callable(statistic):
        raise ValueError(f"statistic must be callable, got {statistic!r}")
    n_resamples = _check_int("n_resamples", n_resamples, minimum=1)
    confidence = _check_open_unit("confidence", confidence)
    seed = _check_int("seed", seed, minimum=0)

    estimate = _scalar("statistic", statistic(arr))
    vectorised = _accepts_axis(statistic, arr)

    n = arr.size
    rng = np.random.default_rng(seed)
    rows_per_block = max(1, _MAX_BLOCK_ELEMENTS // n)
    boot = np.empty(n_resamples, dtype=float)
    for start in range(0, n_resamples, rows_per_block):
        stop = min(start + rows_per_block, n_resamples)
        samples = arr[rng.integers(0, n, size=(stop - start, n))]
        if vectorised:
            block = np.asarray(statistic(samples, axis=-1), dtype=float)
            if block.shape != (stop - start,):
                raise ValueError(
                    "statistic must reduce along axis=-1 to one value per resample, got shape "
                    f"{block.shape} for input shape {samples.shape}"
                )
            boot[start:stop] = block
        else:
            boot[start:stop] = [_scalar("statistic", statistic(row)) for row in samples]

    alpha = 1.0 - confidence
    low, high = np.quantile(boot, [alpha / 2.0, 1.0 - alpha / 2.0])
    return estimate, float(low), float(high)


def paired_difference_ci(
    a: Any,
    b: Any,
    *,
    n_resamples: int = 10_000,
    confidence: float = 0.95,
    seed: int,
) -> tuple[float, float, float]:
    """Percentile bootstrap interval for the mean paired difference ``mean(a - b)``.

    Pairs (same initial state under both conditions) are resampled together, which keeps the
    within-pair correlation that makes the paired design more precise than two independent
    samples.

    Args:
        a: Outcomes under condition A, shape ``(n_pairs,)``, binary or real, ``n_pairs >= 1``.
        b: Outcomes under condition B for the same states, shape ``(n_pairs,)``.
        n_resamples: Number of bootstrap resamples, ``>= 1``.
        confidence: Two-sided confidence level in (0, 1).
        seed: Non-negative seed for ``np.random.default_rng``.

    Returns:
        ``(estimate, low, high)`` with ``estimate = mean(a - b)``.
    """
    a_arr = _as_1d_float("a", a)
    b_arr = _as_1d_float("b", b)
    if a_arr.shape != b_arr.shape:
        raise ValueError(
            f"a and b must have the same length (one entry per pair), got {a_arr.size} and "
            f"{b_arr.size}"
        )
    return bootstrap_ci(
        a_arr - b_arr, np.mean, n_resamples=n_resamples, confidence=confidence, seed=seed
    )


def newcombe_paired_interval(
    both: int, only_a: int, only_b: int, neither: int, *, confidence: float = 0.95
) -> tuple[float, float, float]:
    """Newcombe's hybrid score interval for the difference of paired proportions.

    Newcombe (1998), "Improved confidence intervals for the difference between binomial
    proportions based on paired data", Statistics in Medicine 17:2635-2650, method 10: the
    Wilson intervals of the two marginal rates combined by square-and-add, with the correlation
    phi of the paired table (its numerator ``ad - bc`` shrunk by ``n/2`` toward 0 when positive,
    and phi 0 when a margin is empty). Unlike a bootstrap over pairs it stays a real interval
    where no pair is discordant (both rates 1, both 0): there it is ``[-(1 - l), 1 - l]``
    with ``l`` the Wilson lower bound of n/n, as wide as what n states can rule out.

    Args:
        both: Pairs where both conditions succeed (a).
        only_a: Pairs where only condition A succeeds (b).
        only_b: Pairs where only condition B succeeds (c).
        neither: Pairs where both fail (d); ``a + b + c + d >= 1``.
        confidence: Two-sided confidence level in (0, 1).

    Returns:
        ``(estimate, low, high)`` with ``estimate = (b - c) / n``, the difference rate(A) -
        rate(B); ``-1 <= low <= estimate <= high <= 1``.
    """
    a = _check_int("both", both, minimum=0)
    b = _check_int("only_a", only_a, minimum=0)
    c = _check_int("only_b", only_b, minimum=0)
    d = _check_int("neither", neither, minimum=0)
    n = a + b + c + d
    if n == 0:
        raise ValueError("the paired table must hold at least one pair")
    confidence = _check_open_unit("confidence", confidence)
    p1, p2 = (a + b) / n, (a + c) / n
    l1, u1 = wilson_interval(a + b, n, confidence)
    l2, u2 = wilson_interval(a + c, n, confidence)
    margins = (a + b) * (c + d) * (a + c) * (b + d)
    phi = 0.0
    if margins:
        cross = a * d - b * c
        numerator = max(cross - n / 2.0, 0.0) if cross > 0 else float(cross)
        phi = numerator / math.sqrt(margins)
    lower_a, upper_b = p1 - l1, u2 - p2
    upper_a, lower_b = u1 - p1, p2 - l2
    estimate = p1 - p2
    delta = math.sqrt(max(0.0, lower_a**2 - 2 * phi * lower_a * upper_b + upper_b**2))
    epsilon = math.sqrt(max(0.0, upper_a**2 - 2 * phi * upper_a * lower_b + lower_b**2))
    return estimate, max(-1.0, estimate - delta), min(1.0, estimate + epsilon)


@overload
def iqm(values: Any, axis: None = None) -> float: ...


@overload
def iqm(values: Any, axis: int) -> np.ndarray: ...


def iqm(values: Any, axis: int | None = None) -> float | np.ndarray:
    """Interquartile mean: the mean of the middle 50% of the values.

    Robust to a few outlying episodes yet more efficient than the median; this is the aggregate
    recommended by rliable and equals ``scipy.stats.trim_mean(values, 0.25, axis=axis)``:
    ``floor(0.25 * n)`` values are dropped from each end before averaging.

    Args:
        values: Finite real values. With ``axis=None`` (default) they are flattened, any shape.
        axis: Axis to reduce along, e.g. ``-1`` for a ``(n_resamples, n)`` block of resamples.

    Returns:
        A float for ``axis=None``; otherwise an array with ``axis`` removed.
    """
    try:
        arr = np.asarray(values, dtype=float)
    except (TypeError, ValueError) as exc:
        raise ValueError(f"values must be an array of real numbers: {exc}") from None
    if axis is None:
        arr = arr.reshape(-1)
        axis = 0
    elif isinstance(axis, bool) or not isinstance(axis, Integral):
        raise ValueError(f"axis must be an integer or None, got {axis!r}")
    if not -arr.ndim <= axis < arr.ndim:
        raise ValueError(f"axis must be a valid axis for shape {arr.shape}, got {axis}")
    n = arr.shape[axis]
    if n == 0:
        raise ValueError("values must contain at least one value along the reduced axis")
    if not np.all(np.isfinite(arr)):
        raise ValueError("values must contain only finite values")
    cut = int(0.25 * n)
    middle = np.sort(arr, axis=axis).take(np.arange(cut, n - cut), axis=axis)
    result = middle.mean(axis=axis)
    return float(result) if result.ndim == 0 else result


def iqm_ci(
    values: Any, *, n_resamples: int, confidence: float, seed: int
) -> tuple[float, float, float]:
    """Percentile bootstrap confidence interval for the interquartile mean.

    Args:
        values: Sample, shape ``(n,)`` with ``n >= 1``, finite real values.
        n_resamples: Number of bootstrap resamples, ``>= 1``.
        confidence: Two-sided confidence level in (0, 1).
        seed: Non-negative seed for ``np.random.default_rng``.

    Returns:
        ``(estimate, low, high)`` with ``estimate = iqm(values)``.
    """
    return bootstrap_ci(values, iqm, n_resamples=n_resamples, confidence=confidence, seed=seed)


# --------------------------------------------------------------------------------------------
# Paired test
# --------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class McNemarResult:
    """Outcome of :func:`mcnemar`.

    Attributes:
        only_a: Discordant pairs where A succeeded and B failed.
        only_b: Discordant pairs where B succeeded and A failed.
        p_value: Exact two-sided p-value.
        method: Name of the test, for reports.
    """

    only_a: int
    only_b: int
    p_value: float
    method: str = MCNEMAR_METHOD


def mcnemar(a: Any, b: Any) -> McNemarResult:
    """Exact McNemar test of equal success rates under two paired conditions.

    Only discordant pairs carry information about the difference; under the null each is
    equally likely to favour either condition, so ``only_a ~ Binomial(only_a + only_b, 1/2)``.
    The p-value is the two-sided binomial test's, ``min(1, 2 * P(X <= min(only_a, only_b)))``,
    and 1.0 when there are no discordant pairs.

    Args:
        a: Outcomes under condition A, shape ``(n_pairs,)``, values 0/1 or bool.
        b: Outcomes under condition B on the same initial states, shape ``(n_pairs,)``.

    Returns:
        A :class:`McNemarResult`.
    """
    a_ok = _as_binary("a", a)
    b_ok = _as_binary("b", b)
    if a_ok.shape != b_ok.shape:
        raise ValueError(
            f"a and b must have the same length (one entry per pair), got {a_ok.size} and "
            f"{b_ok.size}"
        )
    only_a = int(np.count_nonzero(a_ok & ~b_ok))
    only_b = int(np.count_nonzero(b_ok & ~a_ok))
    if only_a + only_b == 0:
        return McNemarResult(only_a=0, only_b=0, p_value=1.0)
    # Imported here for the reason given in wilson_interval. P(X <= k) for X ~ Binomial(n, 1/2)
    # is the regularized incomplete beta I_(1/2)(n - k, k + 1), which scipy.special takes from
    # Boost as scipy.stats does (its bdtr loses digits past n of a few thousand); the smaller
    # count as k, so that swapping the conditions gives the very same float.
    from scipy.special import betainc

    k, n = min(only_a, only_b), only_a + only_b
    p_value = min(1.0, 2.0 * float(betainc(n - k, k + 1, 0.5)))
    return McNemarResult(only_a=only_a, only_b=only_b, p_value=p_value)


def holm(p_values: Any) -> list[float]:
    """Holm's step-down adjusted p-values of a family of tests.

    Holm (1979): the i-th smallest of m p-values is multiplied by ``m - i + 1`` (i from 1),
    capped at 1, and made non-decreasing in that order; a test is rejected at level alpha when
    its adjusted p-value is at most alpha, which keeps the family-wise error rate at alpha
    whatever the tests' dependence. Equals statsmodels' ``multipletests(method="holm")[1]``.

    Args:
        p_values: The family's p-values, shape ``(m,)``, each in [0, 1], ``m >= 1``.

    Returns:
        The adjusted p-values, in the order given.
    """
    p = _as_1d_float("p_values", p_values)
    if np.any((p < 0.0) | (p > 1.0)):
        raise ValueError(f"p_values must lie in [0, 1], got {p.tolist()}")
    m = p.size
    order = np.argsort(p, kind="stable")
    scaled = np.minimum(1.0, p[order] * (m - np.arange(m)))
    adjusted = np.empty(m)
    adjusted[order] = np.maximum.accumulate(scaled)
    return [float(x) for x in adjusted]


# --------------------------------------------------------------------------------------------
# Sample sizes
# --------------------------------------------------------------------------------------------


# Beyond any experiment: a plan past it is a typo in the half-width, said in one line.
MAX_PLANNED_EPISODES = 1e15


def episodes_for_halfwidth(halfwidth: float, p: float = 0.5, confidence: float = 0.95) -> int:
    """Episodes needed for a normal-approximation interval of the given half-width.

    Used to plan how many episodes to run: ``n = ceil(z**2 * p * (1 - p) / halfwidth**2)`` with
    ``z`` the two-sided normal quantile. ``p = 0.5`` is the worst case. Results that are
    mathematically integers are not bumped up by floating-point noise.

    Args:
        halfwidth: Desired half-width, in (0, 0.5].
        p: Anticipated success probability, in (0, 1).
        confidence: Two-sided confidence level in (0, 1).

    Returns:
        Number of episodes, ``>= 1``.
    """
    halfwidth = _check_real("halfwidth", halfwidth)
    if not 0.0 < halfwidth <= 0.5:
        raise ValueError(f"halfwidth must be in (0, 0.5], got {halfwidth}")
    p = _check_open_unit("p", p)
    confidence = _check_open_unit("confidence", confidence)
    z = _z_two_sided(confidence)
    # Divided stepwise: halfwidth squared underflows to zero long before halfwidth does.
    need = z * z * p * (1.0 - p) / halfwidth / halfwidth
    if not need <= MAX_PLANNED_EPISODES:
        raise ValueError(
            f"halfwidth {halfwidth:g} needs more than {MAX_PLANNED_EPISODES:.0e} episodes; "
            "expected a wider interval"
        )
    return _ceil_count(need)


def mcnemar_pairs_needed(
    effect: float, discordant: float, power: float = 0.8, confidence: float = 0.95
) -> int:
    """Pairs needed for a two-sided McNemar test to detect a paired difference.

    Connor (1987) normal approximation::

        n = ceil((z_{1-alpha/2} * sqrt(psi) + z_{power} * sqrt(psi - delta**2))**2 / delta**2)

    with ``psi = discordant`` (expected proportion of discordant pairs), ``delta = effect``
    (``P(only A succeeds) - P(only B succeeds)``) and ``alpha = 1 - confidence``.

    Args:
        effect: Paired difference delta, ``0 < |effect| <= discordant``.
        discordant: Discordant proportion psi, ``<= 1``.
        power: Desired power in (0, 1).
        confidence: ``1 - alpha`` of the two-sided test, in (0, 1).

    Returns:
        Number of pairs, ``>= 1``.
    """
    effect = _check_real("effect", effect)
    discordant = _check_real("discordant", discordant)
    if effect == 0.0:
        raise ValueError("effect must be non-zero")
    if not abs(effect) <= discordant <= 1.0:
        raise ValueError(f"discordant must satisfy |effect| <= discordant <= 1, got {discordant}")
    power = _check_open_unit("power", power)
    confidence = _check_open_unit("confidence", confidence)
    z_alpha = _z_two_sided(confidence)
    z_power = NormalDist().inv_cdf(power)
    delta2 = effect * effect
    root = z_alpha * math.sqrt(discordant) + z_power * math.sqrt(max(0.0, discordant - delta2))
    need = root / effect / effect * root  # stepwise: effect squared underflows first
    if not need <= MAX_PLANNED_EPISODES:
        raise ValueError(
            f"effect {effect:g} needs more than {MAX_PLANNED_EPISODES:.0e} pairs; expected a "
            "larger effect"
        )
    return _ceil_count(need)
