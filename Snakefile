# mjtrial: the research-mode experiment. `snakemake -c2` rebuilds every result under
# results/<experiment>/; the design and parameters live in config/config.yaml.
import os
import sys
from pathlib import Path

from mjtrial import foreign_package
from mjtrial.config import (
    ConfigError,
    check_config,
    merge_config,
    parse_config_args,
    preflight,
    read_config_file,
)
from mjtrial.layout import CONFIG_FILE
from mjtrial.stages.manifest import rerun_command

# The code that runs must be the code this checkout stamps and hashes.
if foreign_package(Path.cwd()):
    sys.exit(f"mjtrial: {foreign_package(Path.cwd())}")

# The config file is read here rather than with `configfile:` so that a YAML error or a
# duplicated key is one line too; --configfile and --config values still take precedence.
# Then it is validated before any work, with one line naming the file, the key and the
# expectation (snakemake's validate() prints a multi-line jsonschema dump instead).
# Values given with --config are read as YAML again: Snakemake leaves nested ones as strings.
# The manifest records the command-line values (COMMAND_LINE_CONFIG), so that `mjtrial
# verify` checks the results against the configuration the run used.
try:
    COMMAND_LINE_CONFIG = merge_config(
        config, parse_config_args(workflow.config_settings.config_args)
    )
    config.update(merge_config(read_config_file(CONFIG_FILE), COMMAND_LINE_CONFIG))
    check_config(
        config,
        source=", ".join(map(str, [CONFIG_FILE, *workflow.configfiles])),
        repo_root=Path.cwd(),
        overrides=COMMAND_LINE_CONFIG,
    )
    RERUN_COMMAND = rerun_command(
        [os.path.relpath(f) for f in workflow.configfiles],
        workflow.config_settings.config_args or [],
    )
    for warning in preflight(config, repo_root=Path.cwd()):
        print(warning, file=sys.stderr)
except ConfigError as err:
    sys.exit(f"Config error: {err}")


include: "workflow/rules/common.smk"
include: "workflow/rules/states.smk"
include: "workflow/rules/rollout.smk"
include: "workflow/rules/failures.smk"
include: "workflow/rules/analysis.smk"
include: "workflow/rules/manifest.smk"
include: "workflow/rules/report.smk"
include: "workflow/rules/seal.smk"
include: "workflow/rules/studies.smk"


report: "workflow/report/workflow.rst"


rule all:
    default_target: True
    input:
        manifest=LAYOUT.manifest,
        failures=[LAYOUT.failures] if RECORDED else [],
        report=LAYOUT.report,
        seal=LAYOUT.seal,


# No good result is lost (mjtrial.safekeeping): the results are snapshot before any job runs,
# and whatever a failed job removed is put back as it was.
onstart:
    on_start()


onsuccess:
    SAFEKEEPING.drop()


onerror:
    on_error()
