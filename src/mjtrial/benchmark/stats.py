"""Statistics for the benchmark's report: tasks x methods x training seeds.

Two overall success rates are kept apart and never mixed: the episode mean pools every episode
of every task (a task with more episodes weighs more), the task mean averages the per-task
rates (every task weighs the same). Eight episodes of an easy task all succeeding and two of a
hard task all failing give 80 % and 50 %.

Across training seeds, a method's scores form a ``(runs, tasks)`` matrix (a run is a training
seed, a score its success rate on the task). Its aggregates and their intervals are rliable's
(Agarwal et al. 2021, arXiv:2108.13264; google-research/rliable 1.2.0, ``library.py`` and
``metrics.py``): the interquartile mean of all runs x tasks scores, the median and mean of the
per-task means, the optimality gap, the performance profile, each with a percentile interval
from a stratified bootstrap that resamples runs with replacement within each task. rliable
itself is not a dependency: it draws through numpy's global random state, and it needs arch,
pandas, seaborn and absl (arch 7.2.0 fails to import beside pandas 3).

Paired comparisons of two methods on the same evaluation states use the exact McNemar test per
task, Holm-adjusted across the tasks. Everything here is pure: no I/O, and randomness only
through ``np.random.default_rng(seed)``.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from mjtrial.stats.paired import (
    _MAX_BLOCK_ELEMENTS,
    _as_1d_float,
    _as_binary,
    _check_int,
    _check_open_unit,
    _check_real,
    iqm,
    mcnemar,
    wilson_interval,
)

# The course: at least 3 seeds for a development decision and 5 to 10 for a reported result.
SEEDS_FOR_DEVELOPMENT_DECISION = 3
SEEDS_FOR_REPORTED_RESULT = 5
DEVELOPMENT_DECISION = "development decision"
REPORTED_RESULT = "reported result"

EPISODE_MEAN_METHOD = "Wilson score interval over the pooled episodes"
TASK_MEAN_METHOD = "MOVER over per-task Wilson intervals (Zou, Huang & Zhang 2009)"
STRATIFIED_BOOTSTRAP_METHOD = "percentile bootstrap resampling runs within each task (rliable)"


# --------------------------------------------------------------------------------------------
# Validation
# --------------------------------------------------------------------------------------------


def _per_task_outcomes(outcomes: Any) -> list[np.ndarray]:
    """One boolean array per task, from a sequence of 0/1 arrays or a mapping's values."""
    if isinstance(outcomes, Mapping):
        items = list(outcomes.items())
    elif isinstance(outcomes, Sequence) and not isinstance(outcomes, str):
        items = list(enumerate(outcomes))
    else:
        raise ValueError(
            "outcomes must be a sequence or mapping of per-task 0/1 arrays, got "
            f"{type(outcomes).__name__}"
        )
    if not items:
        raise ValueError("outcomes must hold at least one task")
    return [_as_binary(f"outcomes[{key!r}]", values) for key, values in items]


def _as_scores(scores: Any) -> np.ndarray:
    try:
        arr = np.asarray(scores, dtype=float)
    except (TypeError, ValueError) as exc:
        raise ValueError(f"scores must be an array of real numbers: {exc}") from None
    if arr.ndim != 2:
        raise ValueError(f"scores must be a (runs, tasks) matrix, got shape {arr.shape}")
    if arr.size == 0:
        raise ValueError(f"scores must hold at least one run and one task, got shape {arr.shape}")
    if not np.all(np.isfinite(arr)):
        raise ValueError("scores must contain only finite values")
    return arr


# --------------------------------------------------------------------------------------------
# Two overall success rates
# --------------------------------------------------------------------------------------------


def episode_mean(outcomes: Any, confidence: float = 0.95) -> tuple[float, float, float]:
    """Every episode of every task pooled: total successes over total episodes.

    ``outcomes`` holds one 0/1 (or bool) array per task, as a sequence or a mapping from task
    name; the tasks may have different numbers of episodes. The Wilson interval treats the
    episodes as independent trials of one rate: it says nothing of the spread between training
    seeds (see :func:`seed_spread` and the aggregates). Returns ``(estimate, low, high)``.
    """
    tasks = _per_task_outcomes(outcomes)
    successes = sum(int(np.count_nonzero(t)) for t in tasks)
    n = sum(t.size for t in tasks)
    low, high = wilson_interval(successes, n, confidence)
    return successes / n, low, high


def task_mean(outcomes: Any, confidence: float = 0.95) -> tuple[float, float, float]:
    """The mean of the per-task success rates, every task weighing the same.

    The interval is MOVER (the method of variance estimates recovery) applied to each task's
    Wilson interval ``(l_t, u_t)`` around its rate ``p_t``, for the mean of T rates::

        low  = mean(p) - sqrt(sum((p_t - l_t)**2)) / T
        high = mean(p) + sqrt(sum((u_t - p_t)**2)) / T

    (Zou, Huang & Zhang 2009, Comput. Stat. Data Anal. 53:1080, for linear functions of
    binomial proportions). The tasks are fixed, so only the episodes are sampled. Why not a
    bootstrap of the episodes within each task: a task whose episodes all succeed (or all
    fail) contributes no spread to it, so an easy suite gets a far too narrow interval, and
    8/8 and 0/2 a zero-width one; a Wilson interval keeps its width at 0 and 1. With one task
    this is that task's Wilson interval; it always contains the estimate and stays in [0, 1].
    ``outcomes`` as for :func:`episode_mean`; returns ``(estimate, low, high)``.
    """
    tasks = _per_task_outcomes(outcomes)
    rates = np.array([np.count_nonzero(t) / t.size for t in tasks])
    bounds = np.array(
        [wilson_interval(int(np.count_nonzero(t)), t.size, confidence) for t in tasks]
    )
    estimate = float(rates.mean())
    below = float(np.sqrt(np.sum((rates - bounds[:, 0]) ** 2))) / rates.size
    above = float(np.sqrt(np.sum((bounds[:, 1] - rates) ** 2))) / rates.size
    return estimate, max(0.0, estimate - below), min(1.0, estimate + above)


# --------------------------------------------------------------------------------------------
# Aggregates over a (runs, tasks) matrix, rliable's
# --------------------------------------------------------------------------------------------
# Each reduces the last two axes, so that a stack of bootstrap resamples of shape
# (resamples, runs, tasks) is evaluated at once.


def aggregate_iqm(scores: Any) -> Any:
    """Interquartile mean of all runs x tasks scores, as rliable's ``aggregate_iqm``.

    ``scipy.stats.trim_mean(scores, 0.25, axis=None)``: robust to a few outlying runs and far
    less noisy than the median with few seeds.
    """
    arr = np.asarray(scores, dtype=float)
    return iqm(arr.reshape(*arr.shape[:-2], -1), axis=-1)


def aggregate_median(scores: Any) -> Any:
    """Median over tasks of the per-task mean scores, as rliable's ``aggregate_median``."""
    return np.median(np.asarray(scores, dtype=float).mean(axis=-2), axis=-1)


def aggregate_mean(scores: Any) -> Any:
    """Mean over tasks of the per-task mean scores, as rliable's ``aggregate_mean``."""
    return np.asarray(scores, dtype=float).mean(axis=(-2, -1))


def optimality_gap(scores: Any, gamma: float = 1.0) -> Any:
    """How far the scores fall short of ``gamma``, as rliable's ``aggregate_optimality_gap``.

    ``gamma - mean(min(scores, gamma))`` over all runs x tasks: scores above ``gamma`` earn
    nothing more, so the gap counts only the shortfalls (lower is better).
    """
    gamma = _check_real("gamma", gamma)
    return gamma - np.minimum(np.asarray(scores, dtype=float), gamma).mean(axis=(-2, -1))


def _stratified_bootstrap(
    scores: np.ndarray, statistic: Callable[[np.ndarray], Any], n_resamples: int, seed: int
) -> np.ndarray:
    """Statistic of each stratified resample, shape ``(n_resamples, k)``.

    Resample ``r`` takes ``scores[idx[r, i, j], j]`` with ``idx = rng.integers(0, runs,
    size=(n_resamples, runs, tasks))``: within each task, runs drawn with replacement,
    independently of the other tasks (rliable's ``StratifiedBootstrap``). Drawn in blocks of
    resamples to bound memory; the draws do not depend on the block size.
    """
    runs, tasks = scores.shape
    rng = np.random.default_rng(seed)
    rows_per_block = max(1, _MAX_BLOCK_ELEMENTS // scores.size)
    blocks = []
    for start in range(0, n_resamples, rows_per_block):
        stop = min(start + rows_per_block, n_resamples)
        idx = rng.integers(0, runs, size=(stop - start, runs, tasks))
        block = np.asarray(statistic(scores[idx, np.arange(tasks)]), dtype=float)
        if block.shape[:1] != (stop - start,):
            raise ValueError(
                "statistic must reduce the last two axes of a (resamples, runs, tasks) stack; "
                f"got shape {block.shape} for shape {(stop - start, runs, tasks)}"
            )
        blocks.append(block.reshape(stop - start, -1))
    return np.concatenate(blocks)


def stratified_bootstrap_ci(
    scores: Any,
    statistic: Callable[[np.ndarray], Any] = aggregate_iqm,
    *,
    n_resamples: int = 50_000,
    confidence: float = 0.95,
    seed: int,
) -> tuple[float, float, float]:
    """Stratified percentile bootstrap interval for an aggregate of a (runs, tasks) matrix.

    rliable's ``get_interval_estimates`` with its defaults (``method='percentile'``,
    ``reps=50000``, ``confidence_interval_size=0.95``, ``task_bootstrap=False``): the tasks
    are fixed, the training seeds are what a rerun would change, so runs are resampled within
    each task. The bounds are numpy's linearly interpolated quantiles of the resampled
    aggregates, as arch's percentile interval computes them.

    Args:
        scores: Matrix of shape ``(runs, tasks)``, e.g. a training seed's success rate on each
            task; every task needs the same number of runs.
        statistic: Aggregate reducing the last two axes of a ``(..., runs, tasks)`` array to
            a scalar, like :func:`aggregate_iqm` (default), :func:`aggregate_median`,
            :func:`aggregate_mean` or :func:`optimality_gap`.
        n_resamples: Number of bootstrap resamples, ``>= 1``.
        confidence: Two-sided confidence level in (0, 1).
        seed: Non-negative seed for ``np.random.default_rng``.

    Returns:
        ``(estimate, low, high)`` with ``estimate = statistic(scores)``, interval
        :data:`STRATIFIED_BOOTSTRAP_METHOD`.
    """
    arr = _as_scores(scores)
    if not callable(statistic):
        raise ValueError(f"statistic must be callable, got {statistic!r}")
    n_resamples = _check_int("n_resamples", n_resamples, minimum=1)
    confidence = _check_open_unit("confidence", confidence)
    seed = _check_int("seed", seed, minimum=0)
    estimate = np.asarray(statistic(arr), dtype=float)
    if estimate.size != 1:
        raise ValueError(f"statistic must return a scalar, got shape {estimate.shape}")
    boot = _stratified_bootstrap(arr, statistic, n_resamples, seed)
    alpha = 1.0 - confidence
    low, high = np.quantile(boot[:, 0], [alpha / 2.0, 1.0 - alpha / 2.0])
    return float(estimate.reshape(())), float(low), float(high)


def performance_profile(scores: Any, taus: Any) -> np.ndarray:
    """Fraction of all runs x tasks scores strictly above each threshold tau.

    rliable's score distribution (``create_performance_profile`` with
    ``use_score_distribution=True``): the whole distribution of scores, which shows what one
    aggregate hides, e.g. a method that fails outright on a few tasks. ``scores`` is a
    ``(runs, tasks)`` matrix (or a ``(..., runs, tasks)`` stack), ``taus`` shape ``(k,)``;
    returns shape ``(k,)`` (``(..., k)`` for a stack).
    """
    taus = _as_1d_float("taus", taus)
    arr = np.asarray(scores, dtype=float)
    # One threshold at a time: a (..., runs, tasks, k) comparison would hold k times the block.
    return np.stack([(arr > tau).mean(axis=(-2, -1)) for tau in taus], axis=-1)


def performance_profile_ci(
    scores: Any,
    taus: Any,
    *,
    n_resamples: int = 2_000,
    confidence: float = 0.95,
    seed: int,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Performance profile with a stratified percentile bootstrap interval at each tau.

    rliable's ``create_performance_profile`` with its defaults (``reps=2000``, percentile,
    95 %); the resamples are drawn as in :func:`stratified_bootstrap_ci`, whose arguments
    these are. Returns ``(profile, low, high)``, each of shape ``(k,)``.
    """
    arr = _as_scores(scores)
    taus = _as_1d_float("taus", taus)
    n_resamples = _check_int("n_resamples", n_resamples, minimum=1)
    confidence = _check_open_unit("confidence", confidence)
    seed = _check_int("seed", seed, minimum=0)
    boot = _stratified_bootstrap(arr, lambda s: performance_profile(s, taus), n_resamples, seed)
    alpha = 1.0 - confidence
    low, high = np.quantile(boot, [alpha / 2.0, 1.0 - alpha / 2.0], axis=0)
    return performance_profile(arr, taus), low, high


# --------------------------------------------------------------------------------------------
# Paired differences between two methods, per task
# --------------------------------------------------------------------------------------------


def holm(p_values: Any) -> np.ndarray:
    """Holm step-down adjusted p-values (statsmodels ``multipletests(method="holm")``).

    Controls the family-wise error over all the comparisons of a report without Bonferroni's
    loss of power; an adjusted p-value at most alpha rejects at family-wise level alpha.
    """
    p = _as_1d_float("p_values", p_values)
    if np.any((p < 0.0) | (p > 1.0)):
        raise ValueError("p_values must lie in [0, 1]")
    # Imported here: statsmodels costs Snakemake's process seconds to import.
    from statsmodels.stats.multitest import multipletests

    return np.asarray(multipletests(p, method="holm")[1], dtype=float)


@dataclass(frozen=True)
class TaskComparison:
    """Method A against method B on one task's evaluation states (see :func:`compare_methods`)."""

    task: str
    n_pairs: int
    rate_a: float
    rate_b: float
    difference: float  # rate_a - rate_b
    only_a: int  # states where A succeeded and B failed
    only_b: int
    p_value: float  # exact McNemar, this task alone
    p_holm: float  # Holm-adjusted over all the tasks compared
    significant: bool  # p_holm <= alpha


def compare_methods(
    a: Mapping[str, Any], b: Mapping[str, Any], *, alpha: float = 0.05
) -> tuple[TaskComparison, ...]:
    """Paired comparison of two methods on every task, Holm-adjusted across the tasks.

    Both methods ran the same evaluation states of a task, so their outcomes pair up and the
    exact McNemar test (:func:`mjtrial.stats.mcnemar`) uses only the states they disagree on.
    Testing every task is a family of comparisons: the Holm adjustment keeps the chance of any
    false difference at most ``alpha``. ``a`` maps each task's name to method A's 0/1
    outcomes, one per evaluation state; ``b`` the same tasks to B's on the same states in the
    same order. Returns one :class:`TaskComparison` per task, in ``a``'s order.
    """
    if not isinstance(a, Mapping) or not isinstance(b, Mapping):
        raise ValueError("a and b must be mappings from task name to 0/1 outcomes")
    if not a:
        raise ValueError("a must hold at least one task")
    if set(a) != set(b):
        raise ValueError(
            f"a and b must hold the same tasks; only in a: {sorted(set(a) - set(b))}, only in "
            f"b: {sorted(set(b) - set(a))}"
        )
    alpha = _check_open_unit("alpha", alpha)
    rows = []
    for task in a:
        try:
            test = mcnemar(a[task], b[task])
        except ValueError as exc:
            raise ValueError(f"task {task!r}: {exc}") from None
        a_ok, b_ok = _as_binary("a", a[task]), _as_binary("b", b[task])
        rate_a, rate_b = float(a_ok.mean()), float(b_ok.mean())
        rows.append((task, a_ok.size, rate_a, rate_b, test))
    adjusted = holm([row[4].p_value for row in rows])
    return tuple(
        TaskComparison(
            task=task,
            n_pairs=n,
            rate_a=rate_a,
            rate_b=rate_b,
            difference=rate_a - rate_b,
            only_a=test.only_a,
            only_b=test.only_b,
            p_value=test.p_value,
            p_holm=float(p),
            significant=bool(p <= alpha),
        )
        for (task, n, rate_a, rate_b, test), p in zip(rows, adjusted, strict=True)
    )


# --------------------------------------------------------------------------------------------
# Training seeds
# --------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class SeedSpread:
    """Spread of per-seed success rates: the worst, the typical and the best seed together."""

    n_seeds: int
    minimum: float
    median: float
    maximum: float


def seed_spread(rates: Any) -> SeedSpread:
    """Min, median and max of ``rates``, one per training seed: never the best seed alone."""
    arr = _as_1d_float("rates", rates)
    return SeedSpread(
        n_seeds=arr.size,
        minimum=float(arr.min()),
        median=float(np.median(arr)),
        maximum=float(arr.max()),
    )


def seed_count_label(n_seeds: int, *, require_reported: bool = False) -> str:
    """What a result over ``n_seeds`` training seeds may be used for.

    :data:`REPORTED_RESULT` from :data:`SEEDS_FOR_REPORTED_RESULT` seeds,
    :data:`DEVELOPMENT_DECISION` from :data:`SEEDS_FOR_DEVELOPMENT_DECISION`; fewer seeds
    support neither and raise, as do fewer than :data:`SEEDS_FOR_REPORTED_RESULT` when
    ``require_reported``.
    """
    n_seeds = _check_int("n_seeds", n_seeds, minimum=0)
    if n_seeds >= SEEDS_FOR_REPORTED_RESULT:
        return REPORTED_RESULT
    if require_reported or n_seeds < SEEDS_FOR_DEVELOPMENT_DECISION:
        needed, label = (
            (SEEDS_FOR_REPORTED_RESULT, REPORTED_RESULT)
            if require_reported
            else (SEEDS_FOR_DEVELOPMENT_DECISION, DEVELOPMENT_DECISION)
        )
        raise ValueError(
            f"n_seeds must be >= {needed} for a {label} ({SEEDS_FOR_DEVELOPMENT_DECISION} for a "
            f"{DEVELOPMENT_DECISION}, {SEEDS_FOR_REPORTED_RESULT} for a {REPORTED_RESULT}), "
            f"got {n_seeds}"
        )
    return DEVELOPMENT_DECISION
