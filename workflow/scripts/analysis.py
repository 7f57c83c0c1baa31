"""Snakemake adapter: summarize the rollouts and judge the falsifier (run_analysis)."""

from pathlib import Path

from mjtrial.stages.analysis import run_analysis
from mjtrial.workflow_script import run_job

snakemake = globals()["snakemake"]
conditions = list(snakemake.params.slice["conditions"])
run_job(
    snakemake,
    run_analysis,
    rule="analysis",
    states_path=Path(snakemake.input.states),
    rollout_tables=dict(zip(conditions, map(Path, snakemake.input.rollouts), strict=True)),
    nominal_files=dict(zip(conditions, map(Path, snakemake.input.nominals), strict=True)),
    analysis_slice=snakemake.params.slice,
    output=Path(snakemake.output.summary),
    repo_root=Path.cwd(),
)
