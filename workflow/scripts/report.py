"""Snakemake adapter: figures and report.md (mjtrial.stages.report.write_report_stage)."""

from pathlib import Path

from mjtrial.layout import FIGURES
from mjtrial.stages.report import write_report_stage
from mjtrial.workflow_script import run_job

snakemake = globals()["snakemake"]
config = snakemake.params.slice
run_job(
    snakemake,
    write_report_stage,
    rule="report",
    config=config,
    summary_path=Path(snakemake.input.summary),
    manifest_path=Path(snakemake.input.manifest),
    rollout_tables=dict(
        zip(config["conditions"], map(Path, snakemake.input.rollouts), strict=True)
    ),
    shard_folders={c: list(map(Path, f)) for c, f in snakemake.params.shard_folders.items()},
    model_file=Path(snakemake.input.model),
    figures_dir=Path(snakemake.output[FIGURES[0]]).parent,
    output=Path(snakemake.output.report),
    repo_root=Path.cwd(),
)
