"""The observation model: what stands between a quantity and the number a policy is given.

A reading at control instant k is `value + bias + noise * z[k]`, rounded to the nearest multiple
of `quantum` (`np.round`, ties to even), then lost with probability `dropout` (the policy is
given the last delivered reading again; the reading at instant 0 is always delivered). The
value is the observation's at the measured state (latency is the `Timing`'s); `bias` is the
same constant offset in every episode (a calibration error the run is asked about; a bias drawn
per episode is a state parameter); `noise` is the standard deviation of independent Gaussian
noise, each instant and each component its own draw.

Every parameter is the name of a protocol parameter, so a condition or a sweep can set it
("does encoder noise of 0.01 rad lower success?"). The draws are an episode's own, from its
state values, so every condition meets the same ones (common random numbers: a paired design),
and an episode's readings do not depend on its batch, shard or thread:

    entropy = [*state values as float64 bits (uint64, the task's declaration order),
               first 8 bytes of sha256(observation name) as a little-endian integer]
    z = default_rng([*entropy, 0]).standard_normal((n_controls, size))
    u = default_rng([*entropy, 1]).random(n_controls)      # lost where u[k] < dropout

Values drawn from `states.seed` differ from state to state, so each state has its own draws.
"""

from __future__ import annotations

import hashlib
import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass

import numpy as np

Read = Callable[[int, np.ndarray, np.ndarray | None], np.ndarray]
ROLES = ("noise", "bias", "quantum", "dropout")


@dataclass(frozen=True)
class ObservationModel:
    """The protocol parameters, by name, of an observation's errors (None: no such error).

    Attributes:
      noise: the Gaussian noise's standard deviation, >= 0, in the observation's unit.
      bias: a constant offset added to every reading, in the observation's unit.
      quantum: the resolution readings are rounded to, >= 0 (0: none).
      dropout: the probability, in [0, 1), that a reading is lost and the last one held.
    """

    noise: str | None = None
    bias: str | None = None
    quantum: str | None = None
    dropout: str | None = None

    def parameters(self) -> dict[str, str]:
        """Role -> protocol parameter name, for the roles this model has."""
        return {role: getattr(self, role) for role in ROLES if getattr(self, role) is not None}

    def problem(self, params: Mapping[str, float]) -> str | None:
        """What is wrong with a condition's values of this model's parameters, or None."""
        for role, name in self.parameters().items():
            value = params[name]
            expected = {
                "noise": (value >= 0, ">= 0 (a standard deviation)"),
                "bias": (True, "a number"),
                "quantum": (value >= 0, ">= 0 (0: no rounding)"),
                "dropout": (0 <= value < 1, "a probability in [0, 1)"),
            }[role]
            if not math.isfinite(value) or not expected[0]:
                return f"{role} parameter {name!r} is {value:g}; expected {expected[1]}"
        return None


def name_hash(name: str) -> int:
    """A stable integer of an observation's name (Python's `hash` of a str is salted)."""
    return int.from_bytes(hashlib.sha256(name.encode()).digest()[:8], "little")


def episode_entropy(values: Sequence[float], name: str) -> list[int]:
    """The seed material of one episode's draws for one observation (the module's docstring)."""
    bits = np.asarray(values, dtype=np.float64).view(np.uint64)
    return [*(int(b) for b in bits), name_hash(name)]


def with_errors(
    read: Read,
    model: ObservationModel,
    params: Mapping[str, float],
    *,
    name: str,
    values: np.ndarray,
    n_controls: int,
) -> Read:
    """`read` seen through the observation model.

    Args:
      read: the true observation, (k, states, sensors) -> (n, size); called for k = 0, 1, ...
        in order (a lost reading holds the last delivered one).
      model: its errors; `params` gives their values (checked by `ObservationModel.problem`).
      name: the observation's name (its draws' seed).
      values: (n, n_state_parameters) the episodes' state values, in the batch's row order.
      n_controls: control instants per episode.
    """
    entropy = [episode_entropy(row, name) for row in values]
    std, bias, quantum, dropout = (
        params[p] if p else 0.0 for p in (model.noise, model.bias, model.quantum, model.dropout)
    )
    # instant-major, so each instant's rows are contiguous: (n_controls, n, 1)
    lost = (
        np.stack([np.random.default_rng([*e, 1]).random(n_controls) for e in entropy], 1)[..., None]
        < dropout
        if dropout
        else None
    )
    noise: list[np.ndarray] = []  # (n_controls, n, size) std * z, drawn once the size is known
    last: list[np.ndarray] = []  # the reading delivered at the previous instant

    def observe(k: int, states: np.ndarray, sensors: np.ndarray | None) -> np.ndarray:
        x = np.asarray(read(k, states, sensors), dtype=np.float64)
        if bias:
            x = x + bias
        if std:
            if not noise:
                shape = (n_controls, x.shape[1])
                z = [np.random.default_rng([*e, 0]).standard_normal(shape) for e in entropy]
                noise.append(std * np.stack(z, 1))
            x = x + noise[0][k]
        if quantum:
            with np.errstate(over="ignore"):
                steps = x / quantum
            # a quantum below x's own float spacing (x / quantum overflows: a quantum such as
            # 5e-324): the nearest multiple, as a float, is x itself
            x = np.where(np.isinf(steps) & np.isfinite(x), x, np.round(steps) * quantum)
        if lost is not None:
            if k > 0:
                x = np.where(lost[k], last[0], x)
            last[:] = [x]
        return x

    return observe
