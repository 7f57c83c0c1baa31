rule states:
    output:
        states=LAYOUT.states,
    log:
        LAYOUT.log("states"),
    params:
        slice=config_slice("states", config),
        development=False,
        code=stage_code_hash("states"),
    script:
        "../scripts/states.py"


# Tuning states only, never reported: `snakemake -c2 dev`.
rule development_states:
    output:
        states=LAYOUT.development_states,
    log:
        LAYOUT.log("development_states"),
    params:
        slice=config_slice("states", config),
        development=True,
        code=stage_code_hash("states"),
    script:
        "../scripts/states.py"


rule dev:
    input:
        LAYOUT.development_states,
