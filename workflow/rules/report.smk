rule report:
    input:
        summary=LAYOUT.summary,
        manifest=LAYOUT.manifest,
        states=LAYOUT.states,
        rollouts=per_condition(LAYOUT.rollout_table),
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
        model_sha256=model_content,
        code=stage_code_hash("report"),
    script:
        "../scripts/report.py"
