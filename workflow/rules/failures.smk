# Only when episodes are recorded (recording.episodes is not none).
rule failures:
    input:
        # which episodes failed, so that only the chosen ones' recordings are opened
        tables=per_condition(LAYOUT.rollout_table),
        shards=as_inputs(shard_recordings(CONDITIONS)),
    output:
        failures=LAYOUT.failures,
        table=LAYOUT.failures_table,
    log:
        LAYOUT.log("failures"),
    params:
        slice=config_slice("failures", config),
        conditions=CONDITIONS,
        shard_folders=shard_folders(CONDITIONS),
        code=stage_code_hash("failures"),
    run:
        run_script("failures", input, output, params, wildcards, threads, log, rule)
