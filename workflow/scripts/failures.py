"""Snakemake adapter: gather every failed lift into one replay file (gather_failures)."""

from pathlib import Path

from mjtrial.stages.failures import gather_failures
from mjtrial.workflow_script import run_job

snakemake = globals()["snakemake"]
run_job(
    snakemake,
    gather_failures,
    rule="failures",
    recordings=[Path(p) for p in snakemake.input.recordings],
    tables=[Path(p) for p in snakemake.input.tables],
    output=Path(snakemake.output.failures),
    repo_root=Path.cwd(),
)
