rule analysis:
    input:
        states=LAYOUT.states,
        rollouts=per_condition(LAYOUT.rollout_table),
        nominals=per_condition(LAYOUT.nominal_episode),
        registration=registered_design,
    output:
        summary=report(
            LAYOUT.summary,
            caption="../report/summary.rst",
            category="Results",
        ),
    log:
        LAYOUT.log("analysis"),
    params:
        slice=config_slice("analysis", config),
        task_sha256=task_content,
        code=stage_code_hash("analysis"),
    run:
        run_script("analysis", input, output, params, wildcards, threads, log, rule)
