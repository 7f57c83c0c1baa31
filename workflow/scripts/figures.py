"""Snakemake adapter: the report's figures (mjtrial.stages.report.write_figures_stage)."""

from pathlib import Path

from mjtrial.files.layout import FIGURES
from mjtrial.stages.report import write_figures_stage
from mjtrial.workflow_script import run_job

snakemake = globals()["snakemake"]
config = snakemake.params.slice
run_job(
    snakemake,
    write_figures_stage,
    rule="figures",
    config=config,
    summary_path=Path(snakemake.input.summary),
    rollout_tables=dict(
        zip(config["conditions"], map(Path, snakemake.input.rollouts), strict=True)
    ),
    shard_folders={c: list(map(Path, f)) for c, f in snakemake.params.shard_folders.items()},
    model_file=Path(snakemake.input.model),
    figures_dir=Path(snakemake.output[FIGURES[0]]).parent,
    repo_root=Path.cwd(),
)
