"""Snakemake adapter: roll out one shard of one condition (mjtrial.stages.rollout.run_shard)."""

from mjtrial.sim.simenv import run_in_env

# A variant on another MuJoCo version: the job starts again in that version's environment,
# before anything imports MuJoCo (mjtrial.sim.simenv).
run_in_env(globals()["snakemake"])

from pathlib import Path  # noqa: E402

from mjtrial.nopandas import pyarrow_without_pandas  # noqa: E402

pyarrow_without_pandas()  # the job converts numpy arrays only: no pandas import (0.3 s of CPU)

from mjtrial.stages.rollout import run_shard  # noqa: E402
from mjtrial.workflow_script import run_job  # noqa: E402

snakemake = globals()["snakemake"]
condition = snakemake.params.slice["condition"]
variant = snakemake.params.slice.get("variant")
qualified = f"{variant['name']}/{condition}" if variant else condition
first, stop = snakemake.params.shard
recorded = "recording" in snakemake.output.keys()
run_job(
    snakemake,
    run_shard,
    rule=f"rollout:{qualified}#{snakemake.wildcards.shard}",
    condition_slice=snakemake.params.slice,
    states_path=Path(snakemake.input.states),
    model_file=Path(snakemake.input.model),
    first=first,
    stop=stop,
    output_table=Path(snakemake.output.table),
    output_recording=Path(snakemake.output.recording) if recorded else None,
    unrecorded=None if recorded else Path(snakemake.params.recordings),
    nthread=snakemake.threads,
    repo_root=Path.cwd(),
    # another MuJoCo version's environment (its lock), where the variant names one
    extra_inputs={k: Path(v) for k, v in snakemake.input.items() if k == "simulator_env"},
)
