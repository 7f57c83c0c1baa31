"""Snakemake adapter: the benchmark's report from its summary
(mjtrial.stages.benchmark.write_report)."""

from pathlib import Path

from mjtrial.stages.benchmark import write_report
from mjtrial.workflow_script import run_job

snakemake = globals()["snakemake"]
run_job(
    snakemake,
    write_report,
    rule="benchmark_report",
    summary=Path(snakemake.input.summary),
    closest_calls=Path(snakemake.input.closest_calls),
    output=Path(snakemake.output.report),
    figures_dir=Path(snakemake.output.figures[0]).parent,
    repo_root=Path.cwd(),
)
