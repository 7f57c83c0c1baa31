rule manifest:
    input:
        states=LAYOUT.states,
        rollouts=per_condition(LAYOUT.rollout_table),
        nominals=per_condition(LAYOUT.nominal_episode),
        # the shard tables that ran, and a stopping rule's looks
        shards=run_shard_outputs,
        failures=[LAYOUT.failures, LAYOUT.failures_table] if RECORDED else [],
        summary=LAYOUT.summary,
        model=config["model"],
        # the registered design (the register job's, before the first rollout)
        registration=LAYOUT.registration,
    output:
        manifest=report(
            LAYOUT.manifest,
            caption="../report/manifest.rst",
            category="Provenance",
        ),
    log:
        LAYOUT.log("manifest"),
    params:
        folders=run_shard_folders,
        # The manifest records the whole config, so it depends on all of it.
        slice=config_slice("manifest", config),
        task_sha256=task_content,
        command_line=ConfigSlice(COMMAND_LINE_CONFIG),
        command=RERUN_COMMAND,
        config_file=CONFIG_SOURCE,
        code=stage_code_hash("manifest"),
    run:
        run_script("manifest", input, output, params, wildcards, threads, log, rule)
