# mjtrial: the research-mode experiment. `snakemake -c2` rebuilds every result under
# results/<experiment>/; the design and parameters live in config/config.yaml.
import sys
from pathlib import Path

from mjtrial.config import ConfigError, check_config


configfile: "config/config.yaml"


# Validated before any work, with one line naming the file, the key and the expectation
# (snakemake's validate() prints a multi-line jsonschema dump instead).
try:
    check_config(
        config,
        source=", ".join(str(p) for p in workflow.configfiles) or "config/config.yaml",
        repo_root=Path.cwd(),
    )
except ConfigError as err:
    sys.exit(f"Config error: {err}")


include: "workflow/rules/common.smk"
include: "workflow/rules/states.smk"
include: "workflow/rules/rollout.smk"
include: "workflow/rules/failures.smk"
include: "workflow/rules/analysis.smk"
include: "workflow/rules/manifest.smk"
include: "workflow/rules/report.smk"


report: "workflow/report/workflow.rst"


rule all:
    default_target: True
    input:
        manifest=RESULTS / "manifest.json",
        failures=RESULTS / "replay" / "failures.rrd",
        report=RESULTS / "report.md",
