"""Snakemake adapter: a study's summary, figure and report (mjtrial.stages.studies)."""

from pathlib import Path

from mjtrial.stages.studies import run_dose_response, run_sensitivity
from mjtrial.workflow_script import run_job

snakemake = globals()["snakemake"]
outputs = {
    "output": Path(snakemake.output.summary),
    "report": Path(snakemake.output.report),
    "figures_dir": Path(snakemake.output.figure).parent,
    "repo_root": Path.cwd(),
}
tables = [Path(p) for p in snakemake.input.tables]
if snakemake.rule == "study_sensitivity":
    by_variant, recordings = {}, {}
    for (variant, condition), path in zip(snakemake.params.table_keys, tables, strict=True):
        by_variant.setdefault(variant, {})[condition] = path
    for (variant, condition), folder in zip(
        snakemake.params.recording_keys, snakemake.input.recordings, strict=True
    ):
        recordings.setdefault(variant, {}).setdefault(condition, []).append(Path(folder))
    run_job(
        snakemake,
        run_sensitivity,
        rule="sensitivity",
        study_slice=snakemake.params.slice,
        tables=by_variant,
        recordings=recordings,
        model_file=Path(snakemake.input.model),
        **outputs,
    )
else:
    run_job(
        snakemake,
        run_dose_response,
        rule="dose_response",
        study_slice=snakemake.params.slice,
        states_path=Path(snakemake.input.states),
        tables=dict(zip(snakemake.params["values"], tables, strict=True)),
        **outputs,
    )
