"""Snakemake adapter: one method tuned on one task for one training seed, on development states
only (mjtrial.stages.train.train_method)."""

from pathlib import Path

from mjtrial.stages.train import train_method
from mjtrial.workflow_script import run_job

snakemake = globals()["snakemake"]
run_job(
    snakemake,
    train_method,
    rule=f"train:{snakemake.wildcards.method}:{snakemake.wildcards.task}:{snakemake.wildcards.seed}",
    development_states=Path(snakemake.input.development_states),
    model_file=Path(snakemake.input.model),
    train_slice=snakemake.params.slice,
    output=Path(snakemake.output[0]),
    nthread=snakemake.threads,
    repo_root=Path.cwd(),
)
