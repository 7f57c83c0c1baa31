"""Snakemake adapter: a stopping rule's look after a shard (mjtrial.stages.look.run_look)."""

from pathlib import Path

from mjtrial.stages.look import run_look
from mjtrial.workflow_script import run_job

snakemake = globals()["snakemake"]
shard = snakemake.wildcards.shard
run_job(
    snakemake,
    run_look,
    rule=f"look:{shard}",
    treatment_tables=[Path(p) for p in snakemake.input.treatment],
    baseline_tables=[Path(p) for p in snakemake.input.baseline],
    look_slice=snakemake.params.slice,
    shard=shard,
    output=Path(snakemake.output.look),
    repo_root=Path.cwd(),
)
