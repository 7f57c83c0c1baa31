rule report:
    input:
        summary=LAYOUT.summary,
        manifest=LAYOUT.manifest,
        rollouts=per_condition(LAYOUT.rollout_table),
        shards=run_shard_recordings,
        model=config["model"],
    output:
        **figure_outputs(),
        report=report(
            LAYOUT.report, caption="../report/report_md.rst", category="Report"
        ),
    log:
        LAYOUT.log("report"),
    params:
        # The report renders the design record, so it depends on all of the config.
        slice=config_slice("report", config),
        task_sha256=task_content,
        shard_folders=run_shard_folders_by_condition,
        model_sha256=model_content,
        code=stage_code_hash("report"),
    run:
        run_script("report", input, output, params, wildcards, threads, log, rule)
