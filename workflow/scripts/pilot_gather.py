"""Snakemake adapter: a condition's pilot table from its shards, gathered as any condition's
(mjtrial.stages.rollout.gather_condition), stamped `pilot_gather:<condition>`."""

from pathlib import Path

from mjtrial.stages.rollout import gather_condition
from mjtrial.workflow_script import run_job

snakemake = globals()["snakemake"]
run_job(
    snakemake,
    gather_condition,
    rule=f"pilot_gather:{snakemake.params.slice['condition']}",
    condition_slice=snakemake.params.slice,
    shard_tables=[Path(p) for p in snakemake.input.shards],
    model_file=Path(snakemake.input.model),
    output_table=Path(snakemake.output.table),
    output_nominal=Path(snakemake.output.nominal),
    repo_root=Path.cwd(),
)
