"""Tuning a method's free parameters: CMA-ES (pycma) over some of a task's protocol parameters,
maximising the success rate on development states, within a budget of episodes.

The search runs in the unit box [0, 1]^d, each coordinate mapped linearly to its parameter's
bounds, so one step size suits parameters of any unit. It starts at the box's centre with a
step size of a third of the box (`SIGMA0`). Every generation draws its states from the
development set with a seeded generator, and all its candidates run on the same states: the
ranking CMA-ES uses compares candidates on equal terms, and the noise is reproducible.

pycma does not support a 1-D search (4.5.0 warns "Optimization in 1-D is not supported and may
bail or work poorly", pycma issues #86 and #302); one tuned parameter is searched as pycma's
maintainer suggests there: a 2-D search whose second coordinate the objective ignores.

The final choice: a winner's curse makes the best score on a few states an optimistic pick,
so CMA-ES's final mean and the best few distinct candidates (by score, later generations first
on ties) are each run on every development state, and the highest rate wins (ties: the mean,
then the order listed). Those episodes are reserved from the budget before the search starts.
The search stops before a generation that would spend the rest; the budget is never exceeded.
"""

from __future__ import annotations

import importlib.metadata
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np

from mjtrial.sim.engine import iter_batches
from mjtrial.task import BoundTask, ObservationModel, Task

OPTIMIZER = "cma"
SIGMA0 = 0.3  # the initial step size in the unit box
FINAL_CANDIDATES = 3  # CMA-ES's mean and the best two candidates, rerun on every state
# A success rate on a few states is often flat; a flat generation is not convergence, so
# pycma's flat-fitness and function-value tolerances are off and the budget stops the search.
CMA_OPTIONS = {"tolflatfitness": np.inf, "tolfun": 0, "tolfunhist": 0}


@dataclass(frozen=True)
class Generation:
    """One generation of the search: the states it ran on, its candidates and their rates."""

    states: tuple[int, ...]  # development state positions (rows of the development values)
    mean: dict[str, float]  # CMA-ES's mean when the candidates were drawn, in parameter units
    sigma: float  # its step size, in the unit box
    candidates: tuple[dict[str, float], ...]
    scores: tuple[float, ...]  # success rates on `states`


@dataclass(frozen=True)
class TuningResult:
    """The tuned parameters and how they were found (see the module's docstring)."""

    parameters: dict[str, float]  # the final choice with the fixed values: the method's condition
    score: float  # its rate on every development state (the best of the finalists': optimistic)
    finalists: tuple[dict, ...]  # each: origin, parameters, score on every development state
    tuned: dict[str, tuple[float, float]]
    fixed: dict[str, float]
    history: tuple[Generation, ...]
    episodes_used: int
    budget_episodes: int
    episodes_per_candidate: int
    n_development: int
    seed: int
    stop: str  # "budget", or the pycma criteria that ended the search
    search_dimension: int  # 2 for one tuned parameter (the inert second coordinate)
    popsize: int
    optimizer: str = OPTIMIZER
    optimizer_version: str = importlib.metadata.version("cma")


def default_popsize(n_tuned: int) -> int:
    """pycma's default population for a search over `n_tuned` parameters (its `popsize`
    option, `4 + 3 * log(N)`, in the search's dimension: at least 2, see the module)."""
    return 4 + int(3 * math.log(max(2, n_tuned)))


def minimum_budget(
    n_tuned: int,
    *,
    episodes_per_candidate: int,
    n_development: int,
    final_candidates: int = FINAL_CANDIDATES,
) -> int:
    """The fewest episodes a tuning can run with: one generation, and the finalists on every
    development state."""
    return default_popsize(n_tuned) * episodes_per_candidate + final_candidates * n_development


def check_search(
    task: Task,
    tuned: Mapping[str, Sequence[float]],
    fixed: Mapping[str, float],
    *,
    require_tuned: bool = True,
) -> dict[str, tuple[float, float]]:
    """The tuned parameters' bounds, checked against the task's protocol parameters; a
    problem is a one-line ValueError naming the parameter (`tuned.NAME: ...`, `fixed.NAME:
    ...`). `require_tuned=False` checks fixed values alone."""
    known = {p.name: p for p in task.protocol_parameters}
    if require_tuned and not tuned:
        raise ValueError("tuned: expected at least one protocol parameter to tune")
    out = {}
    for name, bounds in tuned.items():
        if name not in known:
            raise ValueError(f"tuned.{name}: not a protocol parameter of {task.name}")
        low, high = (float(b) for b in bounds)
        if not low < high:
            raise ValueError(f"tuned.{name}: expected low < high, got [{low:g}, {high:g}]")
        for value in (low, high):
            _check_value(known[name], value, f"tuned.{name}", f"[{low:g}, {high:g}]")
        out[name] = (low, high)
    for name, value in fixed.items():
        if name not in known:
            raise ValueError(f"fixed.{name}: not a protocol parameter of {task.name}")
        if name in tuned:
            raise ValueError(f"fixed.{name}: also tuned; expected one or the other")
        _check_value(known[name], float(value), f"fixed.{name}", f"{float(value):g}")
    _check_observation_models(task, out, fixed)
    return out


def _check_observation_models(
    task: Task, tuned: Mapping[str, tuple[float, float]], fixed: Mapping[str, float]
) -> None:
    """Each tuned range's ends and each fixed value against the observation models that use
    the parameter (a noise >= 0, a dropout in [0, 1)): what the rollout would refuse at the
    first candidate that reaches it. Each model's bounds are an interval, so the ends say it
    for the whole range."""
    for o in task.observations:
        for role, name in (o.errors.parameters() if o.errors else {}).items():
            if name not in tuned and name not in fixed:
                continue
            kind = "tuned" if name in tuned else "fixed"
            for value in tuned[name] if name in tuned else (float(fixed[name]),):
                problem = ObservationModel(**{role: name}).problem({name: value})
                if problem is not None:
                    raise ValueError(f"{kind}.{name}: observation {o.name!r}: {problem}")


def _check_value(p, value: float, where: str, got: str) -> None:
    low_ok = p.minimum is None or (value > p.minimum if p.exclusive_minimum else value >= p.minimum)
    if low_ok and (p.maximum is None or value <= p.maximum):
        return
    low = "-inf" if p.minimum is None else f"{p.minimum:g}"
    high = "inf" if p.maximum is None else f"{p.maximum:g}"
    bracket = "(" if p.exclusive_minimum else "["
    raise ValueError(
        f"{where}: expected within the task's bounds {bracket}{low}, {high}], got {got}"
    )


def tune(
    bound: BoundTask,
    development_values: Mapping[str, Sequence[float]],
    *,
    tuned: Mapping[str, Sequence[float]],
    fixed: Mapping[str, float],
    thresholds: Mapping[str, float],
    budget_episodes: int,
    episodes_per_candidate: int,
    seed: int,
    nthread: int = 0,
    final_candidates: int = FINAL_CANDIDATES,
    popsize: int | None = None,
) -> TuningResult:
    """Tune `tuned` ({name: (low, high)}) with `fixed` set, maximising the success rate on the
    development states (state columns -> values), at most `budget_episodes` episodes in all.

    Deterministic for a seed: the candidates come from CMA-ES sampling with its own generator,
    the states from another (both from `numpy.random.SeedSequence(seed)`); episodes never
    depend on `nthread`. pycma's global seed and numpy's global generator are not used.
    """
    # Imported here: pycma imports scipy.stats and matplotlib (52 MB), and this module is
    # imported by Snakemake's process (through mjtrial.benchmark.config), which never tunes.
    import cma

    task = bound.task
    box = check_search(task, tuned, fixed)
    fixed = {k: float(v) for k, v in fixed.items()}
    values = {k: np.asarray(v) for k, v in development_values.items()}
    n_dev = len(next(iter(values.values())))
    if not 1 <= episodes_per_candidate <= n_dev:
        raise ValueError(
            f"episodes_per_candidate: expected 1 to {n_dev} (the development states), "
            f"got {episodes_per_candidate}"
        )
    if final_candidates < 1:
        raise ValueError(f"final_candidates: expected at least 1, got {final_candidates}")
    search_rng, states_rng = (
        np.random.default_rng(s) for s in np.random.SeedSequence(seed).spawn(2)
    )
    dim = max(2, len(box))
    options = {
        **CMA_OPTIONS,
        "bounds": [0.0, 1.0],
        "randn": lambda *shape: search_rng.standard_normal(shape),
        "seed": np.nan,  # pycma's global seeding off: sampling uses `randn` above
        "verbose": -9,
        "verb_log": 0,
        "verb_disp": 0,
    }
    if popsize is not None:
        options["popsize"] = popsize
    es = cma.CMAEvolutionStrategy([0.5] * dim, SIGMA0, options)
    assert popsize is not None or es.popsize == default_popsize(len(box)), es.popsize
    reserve = final_candidates * n_dev
    generation_cost = es.popsize * episodes_per_candidate
    if budget_episodes < reserve + generation_cost:
        raise ValueError(
            f"budget_episodes: expected at least {reserve + generation_cost} (one generation of "
            f"{es.popsize} candidates x {episodes_per_candidate} states, and {final_candidates} "
            f"final candidates x {n_dev} development states), got {budget_episodes}"
        )
    used = 0

    def rate(parameters: dict[str, float], rows: np.ndarray) -> float:
        nonlocal used
        subset = {k: v[rows] for k, v in values.items()}
        # a search's scores: the parameters it chooses are checked where they are evaluated
        batches = iter_batches(
            bound,
            subset,
            {**fixed, **parameters},
            thresholds=thresholds,
            nthread=nthread,
            replay_check=False,
        )
        success = np.concatenate([b.outcome["success"] for b in batches])
        used += len(rows)
        return float(success.mean())

    history, stop = [], "budget"
    while used + generation_cost <= budget_episodes - reserve:
        if es.stop():
            stop = ",".join(sorted(es.stop()))
            break
        mean, sigma = _parameters(task, box, es.result.xfavorite), float(es.sigma)
        xs = es.ask()
        rows = np.sort(states_rng.choice(n_dev, episodes_per_candidate, replace=False))
        candidates = tuple(_parameters(task, box, x) for x in xs)
        scores = tuple(rate(c, rows) for c in candidates)
        es.tell(xs, [-s for s in scores])
        history.append(Generation(tuple(int(r) for r in rows), mean, sigma, candidates, scores))
    finalists = _finalists(task, box, es.result.xfavorite, history, final_candidates)
    judged = [
        {"origin": origin, "parameters": p, "score": rate(p, np.arange(n_dev))}
        for origin, p in finalists
    ]
    best = max(judged, key=lambda f: f["score"])  # the first of equals: the mean first
    return TuningResult(
        parameters={**fixed, **best["parameters"]},
        score=best["score"],
        finalists=tuple(judged),
        tuned=box,
        fixed=fixed,
        history=tuple(history),
        episodes_used=used,
        budget_episodes=int(budget_episodes),
        episodes_per_candidate=int(episodes_per_candidate),
        n_development=n_dev,
        seed=int(seed),
        stop=stop,
        search_dimension=dim,
        popsize=int(es.popsize),
    )


def _parameters(task: Task, box, x) -> dict[str, float]:
    """A point of the unit box as parameter values (integer parameters rounded)."""
    integer = {p.name for p in task.protocol_parameters if p.integer}
    out = {}
    for (name, (low, high)), u in zip(box.items(), x, strict=False):
        value = low + float(np.clip(u, 0.0, 1.0)) * (high - low)
        out[name] = float(round(value)) if name in integer else value
    return out


def _finalists(task, box, mean, history, k: int) -> list[tuple[str, dict[str, float]]]:
    """CMA-ES's final mean, then the best distinct candidates by score (later generations
    first on ties, then the order drawn): `k` in all, fewer if there are not so many."""
    out = [("mean", _parameters(task, box, mean))]
    ranked = sorted(
        (
            (-score, -g, i, candidate)
            for g, gen in enumerate(history)
            for i, (candidate, score) in enumerate(zip(gen.candidates, gen.scores, strict=True))
        ),
        key=lambda r: r[:3],
    )
    for _, g, i, candidate in ranked:
        if len(out) == k:
            break
        if all(candidate != p for _, p in out):
            out.append((f"generation {-g} candidate {i}", candidate))
    return out


def tuned_parameter_record(
    result: TuningResult,
    *,
    development_seed: int,
    task: str | None = None,
    method: str | None = None,
) -> dict:
    """The stamped parameter file's content (JSON-able): what was tuned, how, with what budget
    and seeds, the final choice and the whole search."""
    return {
        "task": task,
        "method": method,
        "parameters": result.parameters,
        "score_on_development": result.score,
        "tuned": {k: list(v) for k, v in result.tuned.items()},
        "fixed": result.fixed,
        "budget_episodes": result.budget_episodes,
        "episodes_used": result.episodes_used,
        "episodes_per_candidate": result.episodes_per_candidate,
        "seed": result.seed,
        "development_states": {"seed": int(development_seed), "n": result.n_development},
        "optimizer": {
            "name": result.optimizer,
            "version": result.optimizer_version,
            "method": "CMA-ES in the unit box, started at its centre",
            "sigma0": SIGMA0,
            "popsize": result.popsize,
            "search_dimension": result.search_dimension,
            "options": {k: str(v) for k, v in CMA_OPTIONS.items()},
            "final_choice": "the highest rate on every development state among CMA-ES's final "
            "mean and the best distinct candidates (ties: the mean, then in order)",
            "stop": result.stop,
        },
        "finalists": list(result.finalists),
        "history": [
            {
                "states": list(g.states),
                "mean": g.mean,
                "sigma": g.sigma,
                "candidates": list(g.candidates),
                "scores": list(g.scores),
            }
            for g in result.history
        ],
    }
