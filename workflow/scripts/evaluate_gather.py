"""Snakemake adapter: an evaluation's table from its shards
(mjtrial.stages.evaluate.gather_evaluation)."""

from pathlib import Path

from mjtrial.stages.evaluate import gather_evaluation
from mjtrial.workflow_script import run_job

snakemake = globals()["snakemake"]
w = snakemake.wildcards
run_job(
    snakemake,
    gather_evaluation,
    rule=f"evaluate_gather:{w.method}:{w.task}:{w.seed}",
    shards=[Path(p) for p in snakemake.input.shards],
    states=Path(snakemake.input.states),
    parameters=Path(snakemake.input.parameters),
    output=Path(snakemake.output[0]),
    repo_root=Path.cwd(),
)
