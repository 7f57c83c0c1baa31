"""What every Snakemake script shares: the rule's log, its stamp line, and one-line errors."""

from __future__ import annotations

import inspect
import logging
import sys
import traceback
from collections.abc import Callable
from pathlib import Path
from typing import Any

from mjtrial import provenance
from mjtrial.stages.stamping import make_stage_stamp

log = logging.getLogger("mjtrial")


def setup_logging(log_path: str | Path, *, mode: str = "w") -> None:
    """Send mjtrial's log to the rule's log file (`mode` "a" appends) and to the console."""
    Path(log_path).parent.mkdir(parents=True, exist_ok=True)
    log.setLevel(logging.INFO)
    log.handlers.clear()
    for handler in (logging.FileHandler(log_path, mode=mode), logging.StreamHandler(sys.stderr)):
        handler.setFormatter(logging.Formatter("%(message)s"))
        log.addHandler(handler)


def run_job(snakemake: Any, stage: Callable[..., Any], /, *, rule: str, **kwargs: Any) -> None:
    """Run one job of a stage: the log begins with the job's stamp; a failure is one line.

    Args:
      snakemake: the `snakemake` object Snakemake gives the script.
      stage: the `mjtrial.stages` function the job calls with `kwargs`.
      rule: the stamp's rule, `<stage>` or `<stage>:<qualifier>` (`rollout:fast`).

    On failure the console and the log get one line, `error: <rule>: <message>`; the log also
    gets the traceback below it, for a bug. The exit status is 1.
    """
    log_path = Path(snakemake.log[0])
    log_path.parent.mkdir(parents=True, exist_ok=True)
    stamp = make_stage_stamp(
        rule, snakemake.params.get("slice", {}), dict(snakemake.input.items()), repo_root=Path.cwd()
    )
    log_path.write_text(provenance.log_stamp_line(stamp) + "\n", encoding="utf-8")
    setup_logging(log_path, mode="a")
    if "rule" in inspect.signature(stage).parameters:  # stages that stamp per job take it too
        kwargs["rule"] = rule
    try:
        stage(**kwargs)
    except Exception as err:  # noqa: BLE001 - every failure is reported the same way
        message = " ".join(str(err).split()) or type(err).__name__
        log.error("error: %s: %s", rule, message)
        with open(log_path, "a", encoding="utf-8") as f:
            f.write("".join(traceback.format_exception(err)))
        sys.exit(1)
