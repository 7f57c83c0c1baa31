"""Snakemake adapter: the results folder as a Provenance Run Crate, with a copy of the
sources (mjtrial.stages.crate.write_crate)."""

from pathlib import Path

from mjtrial.stages.crate import write_crate
from mjtrial.workflow_script import run_job

snakemake = globals()["snakemake"]
run_job(
    snakemake,
    write_crate,
    rule="crate",
    seals=[Path(p) for p in snakemake.input.seals],
    crate_slice=snakemake.params.slice,
    output=Path(snakemake.output.crate),
    source_output=Path(snakemake.output.source),
    repo_root=Path.cwd(),
)
