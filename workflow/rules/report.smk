rule report:
    input:
        summary=RESULTS / "analysis" / "summary.json",
        manifest=RESULTS / "manifest.json",
        states=RESULTS / "states.parquet",
        rollouts=expand(
            RESULTS / "rollouts" / "{condition}.parquet", condition=CONDITIONS
        ),
        model=config["model"],
    output:
        report=report(
            RESULTS / "report.md", caption="../report/report_md.rst", category="Report"
        ),
        success_by_condition=report(
            RESULTS / "figures" / "success_by_condition.png",
            caption="../report/success_by_condition.rst",
            category="Figures",
        ),
        success_by_condition_svg=RESULTS / "figures" / "success_by_condition.svg",
        success_by_mass=report(
            RESULTS / "figures" / "success_by_mass.png",
            caption="../report/success_by_mass.rst",
            category="Figures",
        ),
        success_by_mass_svg=RESULTS / "figures" / "success_by_mass.svg",
        paired_outcomes=report(
            RESULTS / "figures" / "paired_outcomes.png",
            caption="../report/paired_outcomes.rst",
            category="Figures",
        ),
        paired_outcomes_svg=RESULTS / "figures" / "paired_outcomes.svg",
        failure_categories=report(
            RESULTS / "figures" / "failure_categories.png",
            caption="../report/failure_categories.rst",
            category="Figures",
        ),
        failure_categories_svg=RESULTS / "figures" / "failure_categories.svg",
        cube_height=report(
            RESULTS / "figures" / "cube_height.png",
            caption="../report/cube_height.rst",
            category="Figures",
        ),
        cube_height_svg=RESULTS / "figures" / "cube_height.svg",
    log:
        RESULTS / "logs" / "report.log",
    params:
        # The report renders the design record, so it depends on all of the config.
        slice=config_slice("report", config),
        model_sha256=model_sha256,
        code=stage_code_hash("report"),
    script:
        "../scripts/report.py"
