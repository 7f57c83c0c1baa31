"""Snakemake adapter: the benchmark's summary from every evaluation table and parameter file
(mjtrial.stages.benchmark.write_summary)."""

from pathlib import Path

from mjtrial.stages.benchmark import write_summary
from mjtrial.workflow_script import run_job

snakemake = globals()["snakemake"]
keys = snakemake.params.runs
run_job(
    snakemake,
    write_summary,
    rule="benchmark",
    solvability=dict(
        zip(snakemake.params.tasks, map(Path, snakemake.input.solvability), strict=True)
    ),
    evaluations=dict(zip(keys, map(Path, snakemake.input.evaluations), strict=True)),
    parameters=dict(zip(keys, map(Path, snakemake.input.parameters), strict=True)),
    summary_slice=snakemake.params.slice,
    output=Path(snakemake.output.summary),
    repo_root=Path.cwd(),
)
