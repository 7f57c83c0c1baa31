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
        condition=one_of(ALL_CONDITIONS),
    threads: 2
    params:
        slice=rollout_slice,
        model_sha256=model_content,
        code=stage_code_hash("rollout"),
    script:
        "../scripts/rollout.py"


# The design's conditions on a simulator variant (the sensitivity study).
rule rollout_variant:
    input:
        states=LAYOUT.states,
        model=config["model"],
    output:
        table=LAYOUT.rollout_table("{condition}", "{variant}"),
        nominal=LAYOUT.nominal_episode("{condition}", "{variant}"),
        recording=directory(LAYOUT.recordings("{condition}", "{variant}")),
    log:
        LAYOUT.log("rollout_{variant}_{condition}"),
    wildcard_constraints:
        variant=one_of(VARIANTS),
        condition=one_of(CONDITIONS),
    threads: 2
    params:
        slice=variant_slice,
        model_sha256=model_content,
        code=stage_code_hash("rollout_variant"),
    script:
        "../scripts/rollout_variant.py"
