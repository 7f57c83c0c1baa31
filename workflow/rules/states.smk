rule states:
    output:
        states=RESULTS / "states.parquet",
    log:
        RESULTS / "logs" / "states.log",
    params:
        slice=config_slice("states", config),
        code=stage_code_hash("states"),
    script:
        "../scripts/states.py"
