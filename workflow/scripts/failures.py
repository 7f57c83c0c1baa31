"""Snakemake adapter: the failed lifts in one replay file and a table (gather_failures)."""

from pathlib import Path

from mjtrial.stages.failures import gather_failures
from mjtrial.workflow_script import run_job

snakemake = globals()["snakemake"]
conditions = snakemake.params.conditions
run_job(
    snakemake,
    gather_failures,
    rule="failures",
    shard_folders={c: list(map(Path, f)) for c, f in snakemake.params.shard_folders.items()},
    tables=dict(zip(conditions, map(Path, snakemake.input.tables), strict=True)),
    failures_max=snakemake.params.slice["failures_max"],
    output=Path(snakemake.output.failures),
    output_table=Path(snakemake.output.table),
    repo_root=Path.cwd(),
)
