# Each condition's states in shards of rollout.shard_size: one job per (condition, shard), then
# one job that gathers the condition's table from its shards. The nominal model's rollouts sit
# under rollouts/, a simulator variant's under variants/<variant>/rollouts/.


rule rollout:
    input:
        states=LAYOUT.states,
        model=config["model"],
        policy=policy_files,
        # after the registration (register.smk); `ancient`: re-registering reruns no rollout
        registration=ancient(LAYOUT.registration),
    output:
        **shard_recording_output(LAYOUT.shard_recordings("{condition}", "{shard}")),
        table=LAYOUT.shard_table("{condition}", "{shard}"),
    log:
        LAYOUT.log("rollout_{condition}_{shard}"),
    wildcard_constraints:
        condition=one_of(ALL_CONDITIONS),
        shard=SHARD_PATTERN,
    # The longest shards first: at N = 4,000 a slow lift's shard takes 31 s, a fast lift's 19 s,
    # and a fast one started first left a core idle 17 s at the end of the rollouts.
    priority: rollout_priority
    # One engine thread per job, and as many jobs side by side as there are cores: no thread
    # pool to synchronise per batch of episodes (the SLURM profile gives each job 2).
    threads: 1
    params:
        slice=rollout_slice,
        shard=shard_bounds,
        # its recordings folder: one recording nothing removes an earlier run's
        recordings=shard_recordings_of,
        model_sha256=model_content,
        policy_sha256=policy_content,
        code=stage_code_hash("rollout"),
    script:
        "../scripts/rollout.py"


rule gather:
    input:
        shards=shard_tables,
        model=config["model"],
        policy=policy_files,
    output:
        table=report(
            LAYOUT.rollout_table("{condition}"),
            caption="../report/rollout_table.rst",
            category="Tables",
        ),
        nominal=LAYOUT.nominal_episode("{condition}"),
    log:
        LAYOUT.log("gather_{condition}"),
    wildcard_constraints:
        condition=one_of(ALL_CONDITIONS),
    params:
        slice=rollout_slice,
        model_sha256=model_content,
        policy_sha256=policy_content,
        code=stage_code_hash("gather"),
    run:
        run_script("gather", input, output, params, wildcards, threads, log, rule)


# The design's conditions on a simulator variant (the sensitivity study); a variant that names
# another MuJoCo version runs in its environment (simulator_env below).
use rule rollout as rollout_variant with:
    input:
        unpack(simulator_env),
        states=LAYOUT.states,
        model=config["model"],
        registration=ancient(LAYOUT.registration),
    output:
        **shard_recording_output(
            LAYOUT.shard_recordings("{condition}", "{shard}", "{variant}")
        ),
        table=LAYOUT.shard_table("{condition}", "{shard}", "{variant}"),
    log:
        LAYOUT.log("rollout_{variant}_{condition}_{shard}"),
    wildcard_constraints:
        variant=one_of(VARIANTS),
        condition=one_of(CONDITIONS),
        shard=SHARD_PATTERN,


use rule gather as gather_variant with:
    output:
        table=LAYOUT.rollout_table("{condition}", "{variant}"),
        nominal=LAYOUT.nominal_episode("{condition}", "{variant}"),
    log:
        LAYOUT.log("gather_{variant}_{condition}"),
    wildcard_constraints:
        variant=one_of([v for v in VARIANTS if v not in VERSIONS]),
        condition=one_of(CONDITIONS),


# Another MuJoCo version's gather runs its nominal episode in that version's environment: in a
# process of its own (the variant's environment's Python).
rule gather_version:
    input:
        unpack(simulator_env),
        shards=shard_tables,
        model=config["model"],
    output:
        table=LAYOUT.rollout_table("{condition}", "{variant}"),
        nominal=LAYOUT.nominal_episode("{condition}", "{variant}"),
    log:
        LAYOUT.log("gather_{variant}_{condition}"),
    wildcard_constraints:
        variant=one_of(VERSIONS),
        condition=one_of(CONDITIONS),
    params:
        slice=rollout_slice,
        model_sha256=model_content,
        code=stage_code_hash("gather"),
    script:
        "../scripts/gather.py"


# Another MuJoCo version's environment, built by uv (mjtrial.sim.simenv): its lock, written last,
# is what the variant's jobs read. uv's cache lies in envs/uv-cache: offline once cached.
rule simulator_env:
    output:
        lock=lock_path("{version}"),
    log:
        LAYOUT.log("simulator_env_{version}"),
    wildcard_constraints:
        version=one_of(VERSIONS.values()),
    # what it is built from: a changed pin here, or another checkout, builds it again
    params:
        built_from=lambda wildcards: env_build_key(wildcards.version),
    run:
        build_env(wildcards.version, Path(output.lock), log=Path(log[0]))
