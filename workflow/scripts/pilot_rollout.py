"""Snakemake adapter: one shard of one condition on the development states (run_pilot_shard)."""

from pathlib import Path

from mjtrial.nopandas import pyarrow_without_pandas

pyarrow_without_pandas()  # the job converts numpy arrays only: no pandas import (0.3 s of CPU)

from mjtrial.stages.pilot import run_pilot_shard  # noqa: E402
from mjtrial.workflow_script import run_job  # noqa: E402

snakemake = globals()["snakemake"]
first, stop = snakemake.params.shard
run_job(
    snakemake,
    run_pilot_shard,
    rule=f"pilot:{snakemake.params.slice['condition']}#{snakemake.wildcards.shard}",
    condition_slice=snakemake.params.slice,
    states_path=Path(snakemake.input.states),
    model_file=Path(snakemake.input.model),
    first=first,
    stop=stop,
    output_table=Path(snakemake.output.table),
    nthread=snakemake.threads,
    repo_root=Path.cwd(),
)
