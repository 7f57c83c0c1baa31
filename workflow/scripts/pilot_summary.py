"""Snakemake adapter: the pilot's rates per condition (write_pilot_summary)."""

from pathlib import Path

from mjtrial.stages.pilot import write_pilot_summary
from mjtrial.workflow_script import run_job

snakemake = globals()["snakemake"]
conditions = list(snakemake.params.slice["conditions"])
run_job(
    snakemake,
    write_pilot_summary,
    rule="pilot_summary",
    pilot_tables=dict(zip(conditions, map(Path, snakemake.input.tables), strict=True)),
    pilot_slice=snakemake.params.slice,
    output=Path(snakemake.output.summary),
    repo_root=Path.cwd(),
)
