rule rollout:
    input:
        states=RESULTS / "states.parquet",
        model=config["model"],
    output:
        table=report(
            RESULTS / "rollouts" / "{condition}.parquet",
            caption="../report/rollout_table.rst",
            category="Tables",
        ),
        nominal=RESULTS / "rollouts" / "{condition}.nominal.json",
        # one .rrd per episode and the folder's blueprint.rbl: `rerun <folder>/*` opens them
        recording=directory(RESULTS / "rollouts" / "{condition}"),
    log:
        RESULTS / "logs" / "rollout_{condition}.log",
    wildcard_constraints:
        condition="|".join(CONDITIONS),
    threads: 2
    params:
        slice=rollout_slice,
        model_sha256=model_sha256,
        code=stage_code_hash("rollout"),
    script:
        "../scripts/rollout.py"
