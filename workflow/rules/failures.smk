rule failures:
    input:
        recordings=per_condition(LAYOUT.recordings),
        # which episodes failed, so that only their recordings are opened
        tables=per_condition(LAYOUT.rollout_table),
    output:
        failures=LAYOUT.failures,
    log:
        LAYOUT.log("failures"),
    params:
        code=stage_code_hash("failures"),
    script:
        "../scripts/failures.py"
