"""Snakemake adapter: summarize the rollouts and judge the falsifier (run_analysis)."""

from pathlib import Path

from mjtrial.stages.analysis import run_analysis
from mjtrial.workflow_script import run_job

snakemake = globals()["snakemake"]
conditions = list(snakemake.params.slice["conditions"])
# the registration, when there is one (comparisons it did not plan are exploratory): a path,
# or an empty list when nothing is registered
registration = getattr(snakemake.input, "registration", None)
registration = registration if isinstance(registration, str) else None
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
    registration_path=Path(registration) if registration else None,
)
