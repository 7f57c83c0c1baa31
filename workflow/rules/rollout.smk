rule rollout:
    input:
        states=LAYOUT.states,
        model=config["model"],
    output:
        table=report(
            LAYOUT.rollout_table("{condition}"),
            caption="../report/rollout_table.rst",
            category="Tables",
        ),
        nominal=LAYOUT.nominal_episode("{condition}"),
        # one .rrd per episode and the folder's blueprint.rbl: `rerun <folder>/*` opens them
        recording=directory(LAYOUT.recordings("{condition}")),
    log:
        LAYOUT.log("rollout_{condition}"),
    wildcard_constraints:
        condition="|".join(CONDITIONS),
    threads: 2
    params:
        slice=rollout_slice,
        model_sha256=model_content,
        code=stage_code_hash("rollout"),
    script:
        "../scripts/rollout.py"
