rule manifest:
    input:
        states=RESULTS / "states.parquet",
        rollouts=expand(
            RESULTS / "rollouts" / "{condition}.parquet", condition=CONDITIONS
        ),
        nominals=expand(
            RESULTS / "rollouts" / "{condition}.nominal.json", condition=CONDITIONS
        ),
        recordings=expand(RESULTS / "rollouts" / "{condition}", condition=CONDITIONS),
        failures=RESULTS / "replay" / "failures.rrd",
        summary=RESULTS / "analysis" / "summary.json",
        model=config["model"],
    output:
        manifest=report(
            RESULTS / "manifest.json",
            caption="../report/manifest.rst",
            category="Provenance",
        ),
    log:
        RESULTS / "logs" / "manifest.log",
    params:
        # The manifest records the whole config, so it depends on all of it.
        slice=config_slice("manifest", config),
        code=stage_code_hash("manifest"),
    script:
        "../scripts/manifest.py"
