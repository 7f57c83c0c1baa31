"""Snakemake adapter: a condition's table from its shards (gather_condition)."""

from mjtrial.sim.simenv import run_in_env

# A variant on another MuJoCo version: the job starts again in that version's environment,
# before anything imports MuJoCo (mjtrial.sim.simenv).
run_in_env(globals()["snakemake"])

from pathlib import Path  # noqa: E402

from mjtrial.stages.rollout import gather_condition  # noqa: E402
from mjtrial.workflow_script import run_job  # noqa: E402

snakemake = globals()["snakemake"]
condition = snakemake.params.slice["condition"]
variant = snakemake.params.slice.get("variant")
qualified = f"{variant['name']}/{condition}" if variant else condition
run_job(
    snakemake,
    gather_condition,
    rule=f"gather:{qualified}",
    condition_slice=snakemake.params.slice,
    shard_tables=[Path(p) for p in snakemake.input.shards],
    model_file=Path(snakemake.input.model),
    output_table=Path(snakemake.output.table),
    output_nominal=Path(snakemake.output.nominal),
    repo_root=Path.cwd(),
    # another MuJoCo version's environment (its lock), where the variant names one
    extra_inputs={k: Path(v) for k, v in snakemake.input.items() if k == "simulator_env"},
)
