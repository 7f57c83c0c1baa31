rule states:
    output:
        states=RESULTS / "states.parquet",
    log:
        RESULTS / "logs" / "states.log",
    params:
        slice=config_slice("states", config),
        development=False,
        code=stage_code_hash("states"),
    script:
        "../scripts/states.py"


# Tuning states only, never reported: `snakemake -c2 dev`.
rule development_states:
    output:
        states=RESULTS / "development" / "states.parquet",
    log:
        RESULTS / "logs" / "development_states.log",
    params:
        slice=config_slice("states", config),
        development=True,
        code=stage_code_hash("states"),
    script:
        "../scripts/states.py"


rule dev:
    input:
        RESULTS / "development" / "states.parquet",
