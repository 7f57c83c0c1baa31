rule states:
    output:
        states=RESULTS / "states.parquet",
    params:
        states=config["states"],
        code=stage_code_hash("states"),
    log:
        RESULTS / "logs" / "states.log",
    script:
        "../scripts/states.py"
