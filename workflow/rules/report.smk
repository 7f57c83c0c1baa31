# The report's figures, then report.md. The figures need neither the manifest nor the failures
# gathered: they are drawn while the failures job runs (mjtrial.stages.report).


rule figures:
    input:
        summary=LAYOUT.summary,
        rollouts=per_condition(LAYOUT.rollout_table),
        shards=run_shard_recordings,
        model=config["model"],
    output:
        **figure_outputs(),
    log:
        LAYOUT.log("figures"),
    params:
        slice=config_slice("figures", config),
        task_sha256=task_content,
        shard_folders=run_shard_folders_by_condition,
        model_sha256=model_content,
        code=stage_code_hash("figures"),
    run:
        run_script("figures", input, output, params, wildcards, threads, log, rule)


rule report:
    input:
        summary=LAYOUT.summary,
        manifest=LAYOUT.manifest,
        figures=LAYOUT.figure_files(),
        model=config["model"],
    output:
        report=report(
            LAYOUT.report, caption="../report/report_md.rst", category="Report"
        ),
    log:
        LAYOUT.log("report"),
    params:
        # The report renders the design record, so it depends on all of the config.
        slice=config_slice("report", config),
        task_sha256=task_content,
        model_sha256=model_content,
        code=stage_code_hash("report"),
    run:
        run_script("report", input, output, params, wildcards, threads, log, rule)
