rule states:
    output:
        states=LAYOUT.states,
    log:
        LAYOUT.log("states"),
    params:
        slice=config_slice("states", config),
        task_sha256=task_content,
        development=False,
        code=stage_code_hash("states"),
    run:
        run_script("states", input, output, params, wildcards, threads, log, rule)


# Tuning states only, never reported: `snakemake -c2 dev`.
rule development_states:
    output:
        states=LAYOUT.development_states,
    log:
        LAYOUT.log("development_states"),
    params:
        slice=config_slice("states", config),
        task_sha256=task_content,
        development=True,
        code=stage_code_hash("states"),
    run:
        run_script("states", input, output, params, wildcards, threads, log, rule)


rule dev:
    input:
        LAYOUT.development_states,
