"""Snakemake adapter: draw the initial states (mjtrial.stages.states.build_states)."""

from pathlib import Path

from mjtrial.stages.states import build_states, states_rule
from mjtrial.workflow_script import run_job

snakemake = globals()["snakemake"]
run_job(
    snakemake,
    build_states,
    rule=states_rule(development=snakemake.params.development, task=snakemake.params.get("task")),
    states_slice=snakemake.params.slice,
    development=snakemake.params.development,
    output=Path(snakemake.output.states),
    repo_root=Path.cwd(),
)
