# A benchmark (config/benchmark.yaml, mjtrial.benchmark): for each task its evaluation and
# development states; for each task, method and training seed a training job that reads the
# development states only, and an evaluation job on the evaluation states; then the summary
# and the report. Adding a seed adds only its jobs, and what reads every seed.
from mjtrial.benchmark.config import (
    benchmark_runs,
    closest_calls_slice,
    crate_slice,
    evaluate_slice,
    evaluation_shard_range,
    evaluation_shards,
    solvability_slice,
    summary_slice,
    train_slice,
)
from mjtrial.files.layout import BenchmarkLayout
from mjtrial.policy_files.file import policy_file_paths
from mjtrial.provenance import file_sha256, model_sha256
from mjtrial.stages.stamping import config_slice, stage_code_hash
from mjtrial.task import task_files

LAYOUT = BenchmarkLayout.of(config["experiment"])
BENCH = config["benchmark"]
TASKS = list(BENCHMARK_TASKS)
METHODS = list(BENCH["methods"])
# a method marked `none` on a task has no run there
RUNS = [(t, m, str(s)) for t, m, s in benchmark_runs(config)]


wildcard_constraints:
    task="|".join(TASKS),
    method="|".join(METHODS),
    seed=r"\d+",


def experiment_of(wildcards):
    """The experiment config of the job's task."""
    return BENCHMARK_TASKS[wildcards.task].config


def model_of(wildcards):
    return experiment_of(wildcards)["model"]


def task_content(task):
    """Content of the task's files, so that an edit reruns what it defines and a `touch`
    reruns nothing (an installed task: its name)."""
    reference = BENCHMARK_TASKS[task].config["task"]
    if not reference.endswith(".py"):
        return reference
    return ",".join(file_sha256(p) for p in task_files(Path(reference)))


def task_content_of(wildcards):
    return task_content(wildcards.task)


def policy_files_of(wildcards):
    """The run's policy file, its contract and the graph's external data files (a method that
    runs one per training seed), or none: inputs of its training and evaluation, so editing
    any reruns just them.
    """
    files = BENCHMARK_TASKS[wildcards.task].policies.get(wildcards.method, {})
    policy = files.get(int(wildcards.seed))
    return [] if policy is None else [str(p) for p in policy_file_paths(policy)]


def policy_content_of(wildcards):
    """Content of the run's policy files, so a `touch` reruns nothing."""
    return ",".join(file_sha256(p) for p in policy_files_of(wildcards))


rule benchmark_states:
    output:
        states=LAYOUT.task("{task}").states,
    log:
        LAYOUT.log("states_{task}"),
    params:
        slice=lambda w: config_slice("states", experiment_of(w)),
        task_sha256=task_content_of,
        task=lambda w: w.task,
        development=False,
        code=stage_code_hash("states"),
    run:
        run_script("states", input, output, params, wildcards, threads, log, rule)


rule benchmark_development_states:
    output:
        states=LAYOUT.task("{task}").development_states,
    log:
        LAYOUT.log("development_states_{task}"),
    params:
        slice=lambda w: config_slice("states", experiment_of(w)),
        task_sha256=task_content_of,
        task=lambda w: w.task,
        development=True,
        code=stage_code_hash("states"),
    run:
        run_script("states", input, output, params, wildcards, threads, log, rule)


rule train:
    input:
        development_states=LAYOUT.task("{task}").development_states,
        model=model_of,
        policy=policy_files_of,
    output:
        LAYOUT.parameters("{task}", "{method}", "{seed}"),
    log:
        LAYOUT.log("train_{task}_{method}_{seed}"),
    threads: 1
    params:
        slice=lambda w: train_slice(
            config, BENCHMARK_TASKS, w.task, w.method, int(w.seed)
        ),
        model_sha256=lambda w: model_sha256(model_of(w)),
        task_sha256=task_content_of,
        policy_sha256=policy_content_of,
        code=stage_code_hash("train"),
    script:
        "../scripts/train.py"


rule evaluate:
    input:
        states=LAYOUT.task("{task}").states,
        parameters=LAYOUT.parameters("{task}", "{method}", "{seed}"),
        model=model_of,
        policy=policy_files_of,
    output:
        LAYOUT.evaluation_shard("{task}", "{method}", "{seed}", "{shard}"),
    log:
        LAYOUT.log("evaluate_{task}_{method}_{seed}_{shard}"),
    wildcard_constraints:
        shard=r"\d+",
    threads: 1
    params:
        slice=lambda w: evaluate_slice(BENCHMARK_TASKS, w.task),
        shard=lambda w: evaluation_shard_range(BENCHMARK_TASKS, w.task, w.shard),
        model_sha256=lambda w: model_sha256(model_of(w)),
        task_sha256=task_content_of,
        policy_sha256=policy_content_of,
        code=stage_code_hash("evaluate"),
    script:
        "../scripts/evaluate.py"


# On a cluster the gathers run where Snakemake runs: each concatenates a few small tables in
# well under a second, less than a cluster job's submission and start-up, and a group of them
# would ask for a core per gather at once.
localrules:
    evaluate_gather,


rule evaluate_gather:
    input:
        shards=lambda w: [
            LAYOUT.evaluation_shard(w.task, w.method, w.seed, shard)
            for shard in evaluation_shards(BENCHMARK_TASKS, w.task)
        ],
        states=LAYOUT.task("{task}").states,
        parameters=LAYOUT.parameters("{task}", "{method}", "{seed}"),
    output:
        LAYOUT.evaluation("{task}", "{method}", "{seed}"),
    log:
        LAYOUT.log("evaluate_gather_{task}_{method}_{seed}"),
    params:
        code=stage_code_hash("evaluate_gather"),
    run:
        run_script(
            "evaluate_gather", input, output, params, wildcards, threads, log, rule
        )


rule solvability:
    input:
        model=model_of,
    output:
        LAYOUT.solvability("{task}"),
    log:
        LAYOUT.log("solvability_{task}"),
    threads: 1
    params:
        slice=lambda w: solvability_slice(config, BENCHMARK_TASKS, w.task),
        model_sha256=lambda w: model_sha256(model_of(w)),
        task_sha256=task_content_of,
        code=stage_code_hash("solvability"),
    script:
        "../scripts/solvability.py"


rule benchmark_summary:
    input:
        solvability=[LAYOUT.solvability(t) for t in TASKS],
        evaluations=[LAYOUT.evaluation(t, m, s) for t, m, s in RUNS],
        parameters=[LAYOUT.parameters(t, m, s) for t, m, s in RUNS],
    output:
        summary=LAYOUT.summary,
    log:
        LAYOUT.log("benchmark"),
    params:
        runs=[f"{t}:{m}:{s}" for t, m, s in RUNS],
        tasks=TASKS,
        slice=summary_slice(config),
        code=stage_code_hash("benchmark"),
    run:
        run_script("benchmark", input, output, params, wildcards, threads, log, rule)


# Each task's successes of smallest margin and episodes of largest, re-simulated to be watched.
rule closest_calls:
    input:
        states=[LAYOUT.task(t).states for t in TASKS],
        models=[BENCHMARK_TASKS[t].config["model"] for t in TASKS],
        evaluations=[LAYOUT.evaluation(t, m, s) for t, m, s in RUNS],
        parameters=[LAYOUT.parameters(t, m, s) for t, m, s in RUNS],
    output:
        rrd=LAYOUT.closest_calls,
        table=LAYOUT.closest_calls_table,
    log:
        LAYOUT.log("closest_calls"),
    params:
        runs=[f"{t}:{m}:{s}" for t, m, s in RUNS],
        tasks=TASKS,
        slice=closest_calls_slice(config, BENCHMARK_TASKS),
        task_sha256=[task_content(t) for t in TASKS],
        code=stage_code_hash("closest_calls"),
    run:
        run_script(
            "closest_calls", input, output, params, wildcards, threads, log, rule
        )


rule benchmark_report:
    input:
        summary=LAYOUT.summary,
        closest_calls=LAYOUT.closest_calls_table,
    output:
        report=LAYOUT.report,
        figures=LAYOUT.benchmark_figure_files(),
    log:
        LAYOUT.log("benchmark_report"),
    params:
        code=stage_code_hash("benchmark_report"),
    run:
        run_script(
            "benchmark_report", input, output, params, wildcards, threads, log, rule
        )


# The last rules, as an experiment's: the seal (the sha256 of every output, the report and its
# figures included, so that verify sees an edit to any of them) and the results folder as a
# Provenance Run Crate, with a copy of the sources.
BENCHMARK_OUTPUTS = LAYOUT.benchmark_outputs(
    RUNS, {t: evaluation_shards(BENCHMARK_TASKS, t) for t in TASKS}
)


rule benchmark_seal:
    input:
        BENCHMARK_OUTPUTS,
    output:
        seal=LAYOUT.seal,
    log:
        LAYOUT.log("seal"),
    params:
        folders=[],
        code=stage_code_hash("seal"),
    run:
        run_script("seal", input, output, params, wildcards, threads, log, rule)


rule benchmark_crate:
    input:
        seals=[LAYOUT.seal],
    output:
        crate=LAYOUT.crate,
        source=directory(LAYOUT.source),
    log:
        LAYOUT.log("crate"),
    params:
        slice=crate_slice(config, command=RERUN_COMMAND, config_file=CONFIG_SOURCE),
        code=stage_code_hash("crate"),
    run:
        run_script("crate", input, output, params, wildcards, threads, log, rule)


# What `snakemake -c2 --configfile config/benchmark.yaml` builds (the Snakefile's `all`):
# every output is named (a deleted evaluation shard is rebuilt, see the Snakefile's `all`).
ALL_TARGETS = {
    "report": LAYOUT.report,
    "seal": LAYOUT.seal,
    "crate": LAYOUT.crate,
    "outputs": BENCHMARK_OUTPUTS,
    "source": LAYOUT.source,
}
