# The studies: the falsifier judged under simulator variants, and a dose-response sweep.
# `snakemake -c2 sensitivity`, `snakemake -c2 dose_response`, `snakemake -c2 studies`; the
# nominal model's rollouts are the built-in experiment's own.


rule study_sensitivity:
    input:
        tables=list(sensitivity_tables().values()),
        recordings=[f for _, f in sensitivity_recordings()],
        model=config["model"],
    output:
        **study_figure_outputs("sensitivity"),
        summary=report(
            LAYOUT.study_summary("sensitivity"),
            caption="../report/sensitivity.rst",
            category="Studies",
        ),
        report=LAYOUT.study_report("sensitivity"),
    log:
        LAYOUT.log("study_sensitivity"),
    params:
        slice=config_slice("sensitivity", config) if VARIANTS else {},
        table_keys=list(sensitivity_tables()),
        recording_keys=[key for key, _ in sensitivity_recordings()],
        code=stage_code_hash("sensitivity"),
    run:
        run_script("study", input, output, params, wildcards, threads, log, rule)


rule study_dose_response:
    input:
        states=LAYOUT.states,
        tables=[LAYOUT.rollout_table(c) for c in SWEEP.values()],
    output:
        **study_figure_outputs("dose_response"),
        summary=report(
            LAYOUT.study_summary("dose_response"),
            caption="../report/dose_response_summary.rst",
            category="Studies",
        ),
        report=LAYOUT.study_report("dose_response"),
    log:
        LAYOUT.log("study_dose_response"),
    params:
        slice=config_slice("dose_response", config) if SWEEP else {},
        task_sha256=task_content,
        values=list(SWEEP),
        code=stage_code_hash("dose_response"),
    run:
        run_script("study", input, output, params, wildcards, threads, log, rule)


rule seal_study:
    input:
        study_sealed_inputs,
    output:
        seal=LAYOUT.study_seal("{study}"),
    log:
        LAYOUT.log("seal_{study}"),
    wildcard_constraints:
        study="sensitivity|dose_response",
    params:
        folders=study_sealed_folders,
        code=stage_code_hash("seal"),
    run:
        run_script("seal", input, output, params, wildcards, threads, log, rule)


# Each target ends with the folder's crate (crate.smk), which then covers the study.
rule sensitivity:
    input:
        LAYOUT.study_seal("sensitivity"),
        LAYOUT.crate,


rule dose_response:
    input:
        LAYOUT.study_seal("dose_response"),
        LAYOUT.crate,


rule studies:
    input:
        LAYOUT.study_seal("sensitivity"),
        LAYOUT.study_seal("dose_response"),
        LAYOUT.crate,
