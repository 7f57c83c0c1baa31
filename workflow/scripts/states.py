"""Snakemake adapter: draw the initial states (mjtrial.stages.states.build_states)."""

from pathlib import Path

from mjtrial.stages.states import build_states
from mjtrial.workflow_script import setup_logging

snakemake = globals()["snakemake"]
setup_logging(snakemake.log[0])
build_states(
    states_slice=snakemake.params.slice,
    development=snakemake.params.development,
    output=Path(snakemake.output.states),
    repo_root=Path.cwd(),
)
