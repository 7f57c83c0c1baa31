# The pilot, `snakemake -c2 pilot`: the design's conditions on the first pilot.n development
# states (default: all of them), under development/ (laid out as the results folder is), and
# their rates. Not part of `snakemake -c2`:
# it runs before the evaluation is designed to its end, and no rule of the evaluation reads it
# (tests/test_pilot.py checks every rule `all` plans).
DEVELOPMENT = LAYOUT.development


rule pilot_rollout:
    input:
        states=LAYOUT.development_states,
        model=config["model"],
    output:
        table=DEVELOPMENT.shard_table("{condition}", "{shard}"),
    log:
        DEVELOPMENT.log("pilot_{condition}_{shard}"),
    wildcard_constraints:
        condition=one_of(CONDITIONS),
        shard=SHARD_PATTERN,
    threads: 1
    params:
        slice=rollout_slice,
        shard=pilot_shard_bounds,
        model_sha256=model_content,
        code=stage_code_hash("pilot"),
    script:
        "../scripts/pilot_rollout.py"


rule pilot_gather:
    input:
        shards=pilot_shard_tables,
        model=config["model"],
    output:
        table=DEVELOPMENT.rollout_table("{condition}"),
        nominal=DEVELOPMENT.nominal_episode("{condition}"),
    log:
        DEVELOPMENT.log("pilot_gather_{condition}"),
    wildcard_constraints:
        condition=one_of(CONDITIONS),
    params:
        slice=rollout_slice,
        model_sha256=model_content,
        code=stage_code_hash("pilot_gather"),
    run:
        run_script(
            "pilot_gather", input, output, params, wildcards, threads, log, rule
        )


rule pilot_summary:
    input:
        tables=per_condition(DEVELOPMENT.rollout_table),
    output:
        summary=LAYOUT.pilot_summary,
    log:
        DEVELOPMENT.log("pilot_summary"),
    params:
        slice=config_slice("pilot_summary", config),
        task_sha256=task_content,
        code=stage_code_hash("pilot_summary"),
    run:
        run_script(
            "pilot_summary", input, output, params, wildcards, threads, log, rule
        )


rule pilot:
    input:
        LAYOUT.pilot_summary,
