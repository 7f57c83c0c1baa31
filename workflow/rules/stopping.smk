# A stopping rule (config `stopping`): after each shard of the evaluation states, a look at the
# falsifier's pairs run so far (mjtrial.stages.look). Each look is a checkpoint: `run_shards`
# (common.smk) reads its decision before it asks for the next shard, so a stopped
# experiment's later shards are never run, and everything downstream reads the shards that ran.
# Without a `stopping` section there is no look and the DAG is the one without this file.


def look_tables(role):
    """The falsifier's `role` condition's shard tables up to the look's shard, in order."""
    condition = config["design"]["falsifier"][role]

    def tables(wildcards):
        return [
            LAYOUT.shard_table(condition, s)
            for s in SHARDS[: SHARDS.index(wildcards.shard) + 1]
        ]

    return tables


if STOPPING:

    checkpoint look:
        input:
            treatment=look_tables("treatment"),
            baseline=look_tables("baseline"),
        output:
            look=LAYOUT.look("{shard}"),
        log:
            LAYOUT.log("look_{shard}"),
        wildcard_constraints:
            shard=one_of(SHARDS),
        params:
            slice=config_slice("look", config),
            code=stage_code_hash("look"),
        run:
            run_script("look", input, output, params, wildcards, threads, log, rule)
