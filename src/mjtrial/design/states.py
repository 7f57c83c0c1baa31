"""Initial states: drawn once from a seeded generator and shared by every condition.

Each state parameter is drawn uniformly in its range (config `states.ranges`), unless
`states.distributions` names it: a normal (`normal`: mean, std; robosuite's initial joint
noise), or a normal truncated to the range (`truncated_normal`, by the inverse of its CDF at
one uniform draw). Either way one draw of n values per parameter, in the task's order, from
one generator: a uniform parameter's values are those of a config without distributions, bit
for bit.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from typing import Any

import numpy as np
import pyarrow as pa

UNIFORM, NORMAL, TRUNCATED_NORMAL = "uniform", "normal", "truncated_normal"
Distributions = Mapping[str, Mapping[str, Any]] | None


def distribution(
    name: str, ranges: Mapping[str, Sequence[float]], distributions: Distributions = None
) -> dict[str, Any]:
    """How parameter `name` is drawn, as the manifest records it: {"kind": "uniform", "low",
    "high"}, {"kind": "normal", "mean", "std"}, or {"kind": "truncated_normal", "mean", "std",
    "low", "high"}."""
    low, high = (float(v) for v in ranges[name])
    given = (distributions or {}).get(name)
    if given is None:
        return {"kind": UNIFORM, "low": low, "high": high}
    out = {"kind": given["kind"], "mean": float(given["mean"]), "std": float(given["std"])}
    return out | ({"low": low, "high": high} if given["kind"] == TRUNCATED_NORMAL else {})


def draw_parameter(
    rng: np.random.Generator,
    name: str,
    ranges: Mapping[str, Sequence[float]],
    distributions: Distributions,
    n: int,
) -> np.ndarray:
    """n values of parameter `name` from `rng`: one generator call each (`uniform`, `normal`,
    or `uniform` through the truncated normal's inverse CDF, scipy's `truncnorm.ppf`)."""
    d = distribution(name, ranges, distributions)
    if d["kind"] == UNIFORM:
        return rng.uniform(d["low"], d["high"], n)
    if d["kind"] == NORMAL:
        return rng.normal(d["mean"], d["std"], n)
    from scipy.stats import truncnorm  # 0.9 s of import: here, not in Snakemake's process

    a, b = ((d[k] - d["mean"]) / d["std"] for k in ("low", "high"))
    return truncnorm.ppf(rng.uniform(0.0, 1.0, n), a, b, loc=d["mean"], scale=d["std"])


def generate_initial_states(
    *,
    seed: int,
    n: int,
    ranges: Mapping[str, Sequence[float]],
    parameters: Sequence[str],
    distributions: Distributions = None,
) -> pa.Table:
    """N initial states: `default_rng(seed)`, then one draw of n values per parameter
    (`draw_parameter`: uniform unless `distributions` says otherwise).

    Args:
      seed: generator seed.
      n: number of states (>= 1).
      ranges: [low, high] of each parameter.
      distributions: config `states.distributions`: a normal or truncated normal per parameter
        named (None: every parameter uniform).
      parameters: the parameters in draw order (a task's `state_parameters`, in the order it
        declares them: the order is part of the experiment's definition, changing it changes
        every state).

    Returns:
      Table with columns state_id (0..n-1) and the parameters; n rows.
    """
    if n < 1:
        raise ValueError(f"n: expected at least 1 state, got {n}")
    rng = np.random.default_rng(seed)
    columns: dict[str, np.ndarray] = {"state_id": np.arange(n, dtype=np.int64)}
    for name in parameters:
        if name not in ranges:
            raise ValueError(f"ranges.{name}: missing; expected [low, high]")
        low, high = ranges[name]
        if not low < high:
            raise ValueError(f"ranges.{name}: expected low < high, got [{low}, {high}]")
        columns[name] = draw_parameter(rng, name, ranges, distributions, n)
    return pa.table(columns)


# A constraint that keeps under MIN_ACCEPTANCE of PROBE_DRAWS states is refused: the redraws
# would cost over 100 times the states' draw, and a constraint that tight is usually a mistake.
PROBE_DRAWS = 10_000
MIN_ACCEPTANCE = 0.01
# The probe's states asked again alone, in a batch of another size.
ALONE_DRAWS = 100
# Rounds drawn per expected round (1 / the probe's acceptance) before the draw gives up: at an
# acceptance the probe measured, n states kept in that many rounds fail with a chance under
# e^-20 (a binomial of mean 20 n); a constraint that keeps fewer answers by the batch.
ROUNDS_PER_EXPECTED = 20


class ConstraintError(ValueError):
    """A `valid_state` constraint that keeps too few states, or answers with the wrong shape."""


class NotAStateFunctionError(ConstraintError):
    """A `valid_state` constraint whose answer for a state depends on more than its values."""


def draw_valid_states(
    *,
    seed: int,
    n: int,
    ranges: Mapping[str, Sequence[float]],
    parameters: Sequence[str],
    valid: Callable[[Mapping[str, np.ndarray]], np.ndarray],
    distributions: Distributions = None,
) -> tuple[pa.Table, int]:
    """N initial states that satisfy a constraint, and how many drawn states it rejected.

    The rule, deterministic for a seed: one generator `default_rng(seed)` draws rounds, each
    round exactly `generate_initial_states`' draw (n values per parameter, in draw order), the
    first round being its whole table; `valid` is asked about each round's n rows; the valid
    rows are kept in draw order, round after round, until n are kept. The states are those
    first n valid rows, `state_id` 0..n-1. The count returned is the invalid rows drawn before
    the n-th valid one (the redraws).

    Before that, the constraint is asked about `PROBE_DRAWS` states (a generator of the same
    seed, one draw of that many per parameter): under `MIN_ACCEPTANCE` valid is refused
    (`ConstraintError`), as is an answer that is not (rows,) booleans, or one that is not a
    function of each state's values (`check_state_function`). A draw that needs over
    `ROUNDS_PER_EXPECTED` times the rounds the probe's acceptance expects is refused too: the
    constraint answers rounds of n otherwise than the probe's batch.
    """
    if n < 1:
        raise ValueError(f"n: expected at least 1 state, got {n}")
    rate = probe_constraint(
        seed=seed, ranges=ranges, parameters=parameters, valid=valid, distributions=distributions
    )
    rng = np.random.default_rng(seed)
    kept: list[np.ndarray] = []  # per round, its valid rows (k, n_parameters)
    count = rejected = 0
    most = ROUNDS_PER_EXPECTED * int(np.ceil(1 / rate))
    while count < n:
        if len(kept) == most:
            raise ConstraintError(
                f"kept {count} of {n} states in {most:,} rounds of {n}, where the "
                f"{rate:.2%} it accepted of the first {PROBE_DRAWS:,} drawn expects about "
                f"{int(np.ceil(n / rate)):,} draws; expected each state's answer from its own "
                "values alone, not the batch's size"
            )
        block = np.column_stack(
            [draw_parameter(rng, p, ranges, distributions, n) for p in parameters]
        )
        ok = _valid_rows(valid, _table(block, parameters), parameters)
        rows = np.flatnonzero(ok)
        needed = rows[: n - count]
        # the invalid rows before the last one kept (the whole round's if it is not the last)
        seen = ok[: needed[-1] + 1] if count + len(needed) == n else ok
        rejected += int((~seen).sum())
        kept.append(block[needed])
        count += len(needed)
    return _table(np.concatenate(kept), parameters), rejected


def probe_constraint(
    *,
    seed: int,
    ranges: Mapping[str, Sequence[float]],
    parameters: Sequence[str],
    valid: Callable[[Mapping[str, np.ndarray]], np.ndarray],
    distributions: Distributions = None,
) -> float:
    """The share of `PROBE_DRAWS` states (a generator of `seed`) the constraint accepts, after
    the checks `draw_valid_states` makes before it draws (`ConstraintError`): also run by the
    config check, so that a constraint it refuses is refused before any job."""
    probe = generate_initial_states(
        seed=seed,
        n=PROBE_DRAWS,
        ranges=ranges,
        parameters=parameters,
        distributions=distributions,
    )
    answers = _valid_rows(valid, probe, parameters)
    rate = float(np.mean(answers))
    if rate < MIN_ACCEPTANCE:
        raise ConstraintError(
            f"expected at least {MIN_ACCEPTANCE:.0%} of states valid, got {rate:.2%} of the "
            f"first {PROBE_DRAWS:,} drawn"
        )
    check_state_function(valid, probe, parameters, answers)
    return rate


def check_state_function(
    valid: Callable[[Mapping[str, np.ndarray]], np.ndarray],
    table: pa.Table,
    parameters: Sequence[str],
    answers: np.ndarray,
) -> None:
    """Refuse a constraint whose answer for a state is not a function of that state's values:
    asked again about the same states (`answers` is its first answer on `table`), in reverse
    order, and about the first `ALONE_DRAWS` alone, it must answer alike (`ConstraintError`).
    Unseeded randomness, module state, call order, the clock or the batch would let the
    states depend on more than the seed."""
    n, alone = table.num_rows, min(table.num_rows, ALONE_DRAWS)
    reverse = np.arange(n)[::-1]
    asked = (
        (f"asked twice about the same {n:,} states", table, answers),
        (f"asked about the same {n:,} states in reverse order", table.take(reverse), answers[::-1]),
        (f"asked about the first {alone:,} states alone", table.slice(0, alone), answers[:alone]),
    )
    for how, states, expected in asked:
        differ = int((_valid_rows(valid, states, parameters) != expected).sum())
        if differ:
            raise NotAStateFunctionError(
                f"not a function of each state's values: {how}, it answered {differ:,} of them "
                "otherwise; expected each state's answer from its own values alone (no "
                "unseeded randomness, module state, call order, clock or batch size)"
            )


def _table(rows: np.ndarray, parameters: Sequence[str]) -> pa.Table:
    columns = {"state_id": np.arange(len(rows), dtype=np.int64)}
    columns |= {p: np.ascontiguousarray(rows[:, i]) for i, p in enumerate(parameters)}
    return pa.table(columns)


def _valid_rows(
    valid: Callable[[Mapping[str, np.ndarray]], np.ndarray],
    table: pa.Table,
    parameters: Sequence[str],
) -> np.ndarray:
    values = {p: table.column(p).to_numpy() for p in parameters}
    out = np.asarray(valid(values))
    if out.shape != (table.num_rows,) or out.dtype != bool:
        raise ConstraintError(
            f"expected ({table.num_rows},) booleans, one per state, got shape {out.shape} of "
            f"{out.dtype}"
        )
    return out
