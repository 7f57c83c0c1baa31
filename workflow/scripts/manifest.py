"""Snakemake adapter: write the reproducibility record (mjtrial.stages.manifest.write_manifest)."""

from pathlib import Path

from mjtrial.stages.manifest import write_manifest
from mjtrial.workflow_script import run_job

snakemake = globals()["snakemake"]
run_job(
    snakemake,
    write_manifest,
    rule="manifest",
    config=snakemake.params.slice,
    command_line=dict(snakemake.params.command_line),
    command=snakemake.params.command,
    config_file=snakemake.params.config_file,
    summary_path=Path(snakemake.input.summary),
    outputs=[
        Path(snakemake.input.states),
        *map(Path, snakemake.input.rollouts),
        *map(Path, snakemake.input.nominals),
        *map(Path, snakemake.input.shards),
        *map(Path, snakemake.params.folders),
        *map(Path, snakemake.input.failures),
    ],
    model_file=Path(snakemake.input.model),
    output=Path(snakemake.output.manifest),
    repo_root=Path.cwd(),
    registration=Path(snakemake.input.registration),
)
