"""Snakemake adapter: a trained method's parameters on a task's evaluation states
(mjtrial.stages.evaluate.evaluate_method)."""

from pathlib import Path

from mjtrial.stages.evaluate import evaluate_method
from mjtrial.workflow_script import run_job

snakemake = globals()["snakemake"]
w = snakemake.wildcards
run_job(
    snakemake,
    evaluate_method,
    rule=f"evaluate:{w.method}:{w.task}:{w.seed}:{w.shard}",
    states=Path(snakemake.input.states),
    parameters=Path(snakemake.input.parameters),
    model_file=Path(snakemake.input.model),
    evaluate_slice=snakemake.params.slice,
    output=Path(snakemake.output[0]),
    first=snakemake.params.shard[0],
    stop=snakemake.params.shard[1],
    nthread=snakemake.threads,
    repo_root=Path.cwd(),
)
