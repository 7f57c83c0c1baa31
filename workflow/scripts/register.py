"""Snakemake adapter: register the design once (mjtrial.stages.register.register_design)."""

from pathlib import Path

from mjtrial.stages.register import register_design
from mjtrial.workflow_script import run_job

snakemake = globals()["snakemake"]
run_job(
    snakemake,
    register_design,
    rule="register",
    config=snakemake.config,
    output=Path(snakemake.output.registration),
    repo_root=Path.cwd(),
)
