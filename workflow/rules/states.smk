rule states:
    output:
        states=RESULTS / "states.parquet",
    log:
        RESULTS / "logs" / "states.log",
    params:
        states=config["states"],
        code=stage_code_hash("states"),
    script:
        "../scripts/states.py"
