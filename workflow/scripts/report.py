"""Snakemake adapter: report.md (mjtrial.stages.report.write_report_stage)."""

from pathlib import Path

from mjtrial.stages.report import write_report_stage
from mjtrial.workflow_script import run_job

snakemake = globals()["snakemake"]
run_job(
    snakemake,
    write_report_stage,
    rule="report",
    config=snakemake.params.slice,
    summary_path=Path(snakemake.input.summary),
    manifest_path=Path(snakemake.input.manifest),
    figure_paths=list(map(Path, snakemake.input.figures)),
    model_file=Path(snakemake.input.model),
    output=Path(snakemake.output.report),
    repo_root=Path.cwd(),
)
