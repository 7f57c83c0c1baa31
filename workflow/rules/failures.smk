# Only when episodes are recorded (recording.episodes is not none).
rule failures:
    input:
        # which episodes failed, so that only the chosen ones' recordings are opened
        tables=per_condition(LAYOUT.rollout_table),
        shards=run_shard_recordings,
    output:
        failures=LAYOUT.failures,
        table=LAYOUT.failures_table,
    log:
        LAYOUT.log("failures"),
    params:
        slice=config_slice("failures", config),
        conditions=CONDITIONS,
        shard_folders=run_shard_folders_by_condition,
        code=stage_code_hash("failures"),
    # A process of its own: reading the recordings leaves 25-35 MB in the process that ran it
    # (measured alone, at N = 200 and 4,000), which Snakemake's process, running the other
    # light jobs, cannot spare under its 400 MB (benchmarks/bench_memory.py).
    script:
        "../scripts/failures.py"
