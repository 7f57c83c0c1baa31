"""Statistics: the paired binary-outcome experiment's intervals and tests, its sample size and
power, the stopping rule and the planned comparisons.

- `mjtrial.stats.paired`: intervals (Wilson, percentile bootstrap, Newcombe), McNemar's exact
  test, Holm's correction, the IQM and the sample sizes; every public name of it is importable
  from `mjtrial.stats` itself.
- `mjtrial.stats.power`: a design's power before the run (McNemar's exact test).
- `mjtrial.stats.sequential`: stopping early (the mixture e-value, the looks' record).
- `mjtrial.stats.comparisons`: the planned comparisons and the exploratory ones.
"""

from mjtrial.stats.paired import (
    BOOTSTRAP_METHOD,
    HOLM_METHOD,
    MAX_PLANNED_EPISODES,
    MCNEMAR_METHOD,
    NEWCOMBE_METHOD,
    McNemarResult,
    bootstrap_ci,
    episodes_for_halfwidth,
    holm,
    iqm,
    iqm_ci,
    mcnemar,
    mcnemar_pairs_needed,
    newcombe_paired_interval,
    paired_difference_ci,
    wilson_interval,
)

__all__ = [
    "BOOTSTRAP_METHOD",
    "HOLM_METHOD",
    "MAX_PLANNED_EPISODES",
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
