"""What `mjtrial verify`'s recomputation found (`Recomputation`), and how its re-simulated sample
is drawn (`sample_ids`, from a seed drawn at verify time); split from `verify.recompute` by size."""

from __future__ import annotations

import zlib
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from mjtrial import provenance


@dataclass
class Recomputation:
    """What the recomputation found: per output (repository-relative), why it differs."""

    differs: dict[str, str] = field(default_factory=dict)
    # per output, why its re-simulation does not reproduce (two disagree): no sign of tampering
    irreproducible: dict[str, str] = field(default_factory=dict)
    recomputed: int = 0
    resimulated: int = 0
    episodes: int = 0  # in the shards the stamps judged current
    coverage: str = ""  # why that many were re-simulated (`verify.coverage`)
    recorded: int = 0  # recorded episodes compared with their rows
    seed: int = 0  # the re-simulated sample's
    # variants on another MuJoCo version: re-simulated in its environment (folder ->
    # conditions), or not, and why (why -> conditions)
    in_env: dict[str, list[str]] = field(default_factory=dict)
    elsewhere: dict[str, list[str]] = field(default_factory=dict)

    def line(self) -> str:
        other = "".join(
            f"; re-simulated {', '.join(conditions)} in {folder}"
            for folder, conditions in self.in_env.items()
        ) + "".join(
            f"; not re-simulated: {', '.join(conditions)} ({why})"
            for why, conditions in self.elsewhere.items()
        )
        return (
            f"recomputed {self.recomputed} outputs from their inputs, compared "
            f"{self.recorded} recorded episodes with their rows and re-simulated "
            f"{self.resimulated} of {self.episodes} episodes (sample seed {self.seed}: --seed "
            f"{self.seed} draws it again{'; ' + self.coverage if self.coverage else ''}): "
            f"{len(self.differs)} differ{other}"
        )


def _platform_note(stamp: Mapping[str, Any], mujoco_version: str) -> str:
    """Where the record was made, when that is not here (on MuJoCo `mujoco_version`): another
    CPU or MuJoCo build may explain a re-simulation that differs."""
    then = (stamp.get("versions", {}).get("mujoco"), stamp.get("platform", {}).get("cpu_model"))
    now = (mujoco_version, provenance.platform_fingerprint()["cpu_model"])
    if then == now:
        return ""
    return (
        f" (recorded with MuJoCo {then[0]} on {then[1]}; re-simulated with MuJoCo {now[0]} "
        f"on {now[1]})"
    )


def fresh_seed() -> int:
    """A seed for the re-simulated sample, drawn from the system's entropy at verify time."""
    return int(np.random.SeedSequence().entropy % 2**32)


def sample_ids(first: int, stop: int, k: int, *, seed: int, key: str) -> list[int]:
    """A sample of `k` state ids in [first, stop), fixed by `seed` and `key` (the shard)."""
    ids = np.arange(first, stop)
    if k >= ids.size:
        return ids.tolist()
    rng = np.random.default_rng([seed, zlib.crc32(key.encode())])
    return sorted(rng.choice(ids, size=k, replace=False).tolist())
