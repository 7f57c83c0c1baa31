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
        summary=RESULTS / "analysis" / "summary.json",
    log:
        RESULTS / "logs" / "analysis.log",
    params:
        conditions=config["conditions"],
        falsifier=config["design"]["falsifier"],
        analysis=config["analysis"],
        code=stage_code_hash("analysis"),
    script:
        "../scripts/analysis.py"
