# The design is registered here, once (mjtrial.design.registration): after the states job, the last
# check that can refuse the design, and before every evaluation rollout, which reads the file
# (`ancient`: `mjtrial register --again` reruns no rollout). Never on a dry run, nor for the
# `dev` and `pilot` targets, which plan no rollout of the evaluation. No params: the job runs
# when the file is missing, or when Snakemake is told to (`--forceall`), and then puts back
# the registration Snakemake removed; it never registers over one.
rule register:
    input:
        states=ancient(LAYOUT.states),
    output:
        registration=LAYOUT.registration,
    log:
        LAYOUT.log("register"),
    # before the rollouts it precedes, whatever their priority (their physics steps)
    priority: 1_000_000_000
    run:
        # the design is the whole config: no params, whose change would rerun the job
        run_script(
            "register", input, output, params, wildcards, threads, log, rule, config
        )
