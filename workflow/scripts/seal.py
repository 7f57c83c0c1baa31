"""Snakemake adapter: seal every output (mjtrial.stages.seal.seal_outputs)."""

from pathlib import Path

from mjtrial.stages.seal import seal_outputs
from mjtrial.workflow_script import run_job

snakemake = globals()["snakemake"]
registration = getattr(snakemake.input, "registration", None)
run_job(
    snakemake,
    seal_outputs,
    rule=f"seal:{snakemake.wildcards.study}" if "study" in snakemake.wildcards.keys() else "seal",
    outputs=sorted(
        {*map(Path, snakemake.input), *map(Path, snakemake.params.folders)}
        - ({Path(registration)} if registration else set())
    ),
    output=Path(snakemake.output.seal),
    repo_root=Path.cwd(),
    registration=Path(registration) if registration else None,
)
