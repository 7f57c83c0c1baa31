"""Snakemake adapter: the benchmark's closest calls, re-simulated into one replay file
(mjtrial.stages.closest_calls.write_closest_calls)."""

from pathlib import Path

from mjtrial.stages.closest_calls import write_closest_calls
from mjtrial.workflow_script import run_job

snakemake = globals()["snakemake"]
keys = snakemake.params.runs
tasks = snakemake.params.tasks
run_job(
    snakemake,
    write_closest_calls,
    rule="closest_calls",
    closest_slice=snakemake.params.slice,
    states=dict(zip(tasks, map(Path, snakemake.input.states), strict=True)),
    models=dict(zip(tasks, map(Path, snakemake.input.models), strict=True)),
    evaluations=dict(zip(keys, map(Path, snakemake.input.evaluations), strict=True)),
    parameters=dict(zip(keys, map(Path, snakemake.input.parameters), strict=True)),
    output_rrd=Path(snakemake.output.rrd),
    output_table=Path(snakemake.output.table),
    repo_root=Path.cwd(),
)
