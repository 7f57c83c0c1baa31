"""Snakemake adapter: a benchmark task's probe states under its reference controller
(mjtrial.stages.benchmark.write_solvability)."""

from pathlib import Path

from mjtrial.stages.benchmark import write_solvability
from mjtrial.workflow_script import run_job

snakemake = globals()["snakemake"]
run_job(
    snakemake,
    write_solvability,
    rule=f"solvability:{snakemake.wildcards.task}",
    solvability_slice=snakemake.params.slice,
    model_file=Path(snakemake.input.model),
    output=Path(snakemake.output[0]),
    nthread=snakemake.threads,
    repo_root=Path.cwd(),
)
