rule failures:
    input:
        recordings=expand(RESULTS / "rollouts" / "{condition}", condition=CONDITIONS),
        # which episodes failed, so that only their recordings are opened
        tables=expand(
            RESULTS / "rollouts" / "{condition}.parquet", condition=CONDITIONS
        ),
    output:
        failures=RESULTS / "replay" / "failures.rrd",
    log:
        RESULTS / "logs" / "failures.log",
    params:
        code=stage_code_hash("failures"),
    script:
        "../scripts/failures.py"
