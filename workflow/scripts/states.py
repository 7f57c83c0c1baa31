"""Snakemake adapter: draw the initial states (mjtrial.pipeline.build_states)."""

from pathlib import Path

from mjtrial.pipeline import build_states
from mjtrial.workflow_script import setup_logging

snakemake = globals()["snakemake"]
setup_logging(snakemake.log[0])
build_states(
    states_slice=snakemake.params.slice,
    development=snakemake.params.development,
    output=Path(snakemake.output.states),
    repo_root=Path.cwd(),
)
