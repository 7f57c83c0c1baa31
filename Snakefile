# mjtrial: the research-mode experiment. `snakemake -c2` rebuilds every result under
# results/<experiment>/; the design and parameters live in config/config.yaml.
import os
import sys
from pathlib import Path

from mjtrial import foreign_package
from mjtrial.benchmark import is_benchmark
from mjtrial.config import (
    ConfigError,
    check_config,
    preflight,
    rerun_command,
    run_configuration,
)
from mjtrial.config.passes import CONFIG_CHECKS, remember_passes
from mjtrial.files.layout import COMPILED_MODELS
from mjtrial.sim.physics import keep_compiled_models

# The code that runs must be the code this checkout stamps and hashes.
if foreign_package(Path.cwd()):
    sys.exit(f"mjtrial: {foreign_package(Path.cwd())}")

# The model compiled by the config check is kept for the jobs, which read it instead of
# compiling it again (mjtrial.sim.physics.load_model).
keep_compiled_models(COMPILED_MODELS)
# A config check that passed is not simulated again at the next start while nothing it reads
# has changed (mjtrial.config.passes).
remember_passes(CONFIG_CHECKS)

# The config file is read here rather than with `configfile:` so that a YAML error or a
# duplicated key is one line too. It is config/config.yaml, or a `--configfile` that names an
# experiment (a whole experiment, such as config/cartpole_latency.yaml, in its place); other
# --configfile and --config values take precedence over it (mjtrial.config.run_configuration).
# Then it is validated before any work, with one line naming the file, the key and the
# expectation (snakemake's validate() prints a multi-line jsonschema dump instead).
# Values given with --config are read as YAML again: Snakemake leaves nested ones as strings.
# The manifest records the run's file (CONFIG_SOURCE) and the command-line values
# (COMMAND_LINE_CONFIG), so that `mjtrial verify` checks the results against the
# configuration the run used.
try:
    CONFIG_SOURCE, COMMAND_LINE_CONFIG, run_config = run_configuration(
        workflow.configfiles,
        workflow.config_settings.config_args,
        config,
        repo_root=Path.cwd(),
    )
    CONFIG_SOURCE = os.path.relpath(CONFIG_SOURCE)
    config.clear()
    config.update(run_config)
    # A benchmark's config (config/benchmark.yaml) names tasks by their experiment configs
    # and methods to tune and compare on them (mjtrial.benchmark).
    BENCHMARK = is_benchmark(config)
    RERUN_COMMAND = rerun_command(
        [os.path.relpath(f) for f in workflow.configfiles],
        workflow.config_settings.config_args or [],
    )
    if BENCHMARK:
        from mjtrial.benchmark.config import check_benchmark_config

        BENCHMARK_TASKS = check_benchmark_config(
            config, source=CONFIG_SOURCE, repo_root=Path.cwd()
        )
    else:
        check_config(
            config,
            source=", ".join(
                dict.fromkeys(
                    [CONFIG_SOURCE, *map(os.path.relpath, workflow.configfiles)]
                )
            ),
            repo_root=Path.cwd(),
            overrides=COMMAND_LINE_CONFIG,
        )
        for warning in preflight(config, repo_root=Path.cwd()):
            print(warning, file=sys.stderr)
except ConfigError as err:
    sys.exit(f"Config error: {err}")


if BENCHMARK:

    include: "workflow/rules/benchmark.smk"

else:

    include: "workflow/rules/common.smk"
    include: "workflow/rules/states.smk"
    include: "workflow/rules/register.smk"
    include: "workflow/rules/rollout.smk"
    include: "workflow/rules/stopping.smk"
    include: "workflow/rules/failures.smk"
    include: "workflow/rules/analysis.smk"
    include: "workflow/rules/manifest.smk"
    include: "workflow/rules/report.smk"
    include: "workflow/rules/seal.smk"
    include: "workflow/rules/studies.smk"
    include: "workflow/rules/pilot.smk"
    include: "workflow/rules/crate.smk"

    report: "workflow/report/workflow.rst"

    ALL_TARGETS = {
        "manifest": LAYOUT.manifest,
        "failures": [LAYOUT.failures] if RECORDED else [],
        "report": LAYOUT.report,
        "seal": LAYOUT.seal,
        "crate": LAYOUT.crate,
        "outputs": sealed_outputs,
        "source": LAYOUT.source,
    }


include: "workflow/rules/run.smk"


# The default target (here: an included file's rules never are): every result of the run,
# each named: Snakemake rebuilds a missing file only when a job that reads it runs, or when a
# target names it, so a deleted shard (read by its gather only) is rebuilt, with what reads it.
rule all:
    default_target: True
    input:
        **ALL_TARGETS,


# No good result is lost (mjtrial.files.safekeeping): the results are snapshot before any job runs,
# and whatever a failed job removed is put back as it was.
onstart:
    on_start()


onsuccess:
    on_success()


onerror:
    on_error()
