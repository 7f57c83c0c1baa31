rule analysis:
    input:
        states=RESULTS / "states.parquet",
        rollouts=expand(
            RESULTS / "rollouts" / "{condition}.parquet", condition=CONDITIONS
        ),
        nominals=expand(
            RESULTS / "rollouts" / "{condition}.nominal.json", condition=CONDITIONS
        ),
    output:
        summary=report(
            RESULTS / "analysis" / "summary.json",
            caption="../report/summary.rst",
            category="Results",
        ),
    log:
        RESULTS / "logs" / "analysis.log",
    params:
        slice=config_slice("analysis", config),
        code=stage_code_hash("analysis"),
    script:
        "../scripts/analysis.py"
