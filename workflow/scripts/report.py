"""Snakemake adapter: figures and report.md (mjtrial.stages.report.write_report_stage)."""

from pathlib import Path

from mjtrial.stages.report import write_report_stage
from mjtrial.workflow_script import setup_logging

snakemake = globals()["snakemake"]
setup_logging(snakemake.log[0])
config = snakemake.params.slice
write_report_stage(
    config=config,
    summary_path=Path(snakemake.input.summary),
    manifest_path=Path(snakemake.input.manifest),
    states_path=Path(snakemake.input.states),
    rollout_tables=dict(
        zip(config["conditions"], map(Path, snakemake.input.rollouts), strict=True)
    ),
    model_file=Path(snakemake.input.model),
    figures_dir=Path(snakemake.output.report).parent / "figures",
    output=Path(snakemake.output.report),
    repo_root=Path.cwd(),
)
