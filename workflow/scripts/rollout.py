"""Snakemake adapter: roll out one condition (mjtrial.stages.rollout.run_condition)."""

from pathlib import Path

from mjtrial.stages.rollout import run_condition
from mjtrial.workflow_script import run_job

snakemake = globals()["snakemake"]
run_job(
    snakemake,
    run_condition,
    rule=f"rollout:{snakemake.wildcards.condition}",
    condition_slice=snakemake.params.slice,
    states_path=Path(snakemake.input.states),
    model_file=Path(snakemake.input.model),
    output_table=Path(snakemake.output.table),
    output_nominal=Path(snakemake.output.nominal),
    output_recording=Path(snakemake.output.recording),
    nthread=snakemake.threads,
    repo_root=Path.cwd(),
)
