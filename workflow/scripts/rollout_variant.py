"""Snakemake adapter: one condition on a simulator variant (run_variant_condition)."""

from pathlib import Path

from mjtrial.stages.rollout_variant import run_variant_condition
from mjtrial.workflow_script import run_job

snakemake = globals()["snakemake"]
run_job(
    snakemake,
    run_variant_condition,
    rule=f"rollout_variant:{snakemake.wildcards.variant}/{snakemake.wildcards.condition}",
    variant_slice=snakemake.params.slice,
    states_path=Path(snakemake.input.states),
    model_file=Path(snakemake.input.model),
    output_table=Path(snakemake.output.table),
    output_nominal=Path(snakemake.output.nominal),
    output_recording=Path(snakemake.output.recording),
    nthread=snakemake.threads,
    repo_root=Path.cwd(),
)
