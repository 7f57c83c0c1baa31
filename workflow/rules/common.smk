import sys
from pathlib import Path

from mjtrial.layout import FIGURES, Layout
from mjtrial.provenance import model_sha256
from mjtrial.safekeeping import Snapshot, remove_stale_temporaries
from mjtrial.stages.stamping import config_slice, stage_code_hash

# Every path comes from the layout; rules pass wildcards ("{condition}") to its methods.
LAYOUT = Layout.of(config["experiment"])
CONDITIONS = list(config["conditions"])


def rollout_slice(wildcards):
    """The config a condition's rollout depends on: its own protocol parameters only."""
    return config_slice("rollout", config, condition=wildcards.condition)


def model_content(wildcards=None):
    """Content of the model, so a checkout that only touches its mtime reruns nothing."""
    return model_sha256(config["model"])


def per_condition(path_of):
    """One path per condition: `path_of` is a layout method such as LAYOUT.rollout_table."""
    return [path_of(c) for c in CONDITIONS]


def figure_outputs():
    """The report's figures as named outputs: `<name>` (the PNG, shown in Snakemake's HTML
    report with its caption) and `<name>_svg`."""
    outputs = {}
    for name in FIGURES:
        outputs[name] = report(
            LAYOUT.figure(name, "png"),
            caption=f"../report/{name}.rst",
            category="Figures",
        )
        outputs[f"{name}_svg"] = LAYOUT.figure(name, "svg")
    return outputs


SAFEKEEPING = Snapshot(LAYOUT.root, logs=LAYOUT.logs_dir, workdir=Path.cwd())


def on_start():
    """Clear what killed jobs left, put back what a killed run removed, take the snapshot."""
    for path in remove_stale_temporaries(LAYOUT.root):
        print(f"mjtrial: removed {path}, left by a killed job", file=sys.stderr)
    restored = SAFEKEEPING.take()
    if restored:
        print(
            f"mjtrial: the last run was killed; put back {len(restored)} output(s) it had "
            f"removed: {', '.join(map(str, restored))}",
            file=sys.stderr,
        )


def on_error():
    """Put back every output the failed run removed, and say so."""
    restored = SAFEKEEPING.restore()
    SAFEKEEPING.drop()
    if restored:
        print(
            f"mjtrial: a job failed; the previous results were put back unchanged: "
            f"{', '.join(map(str, restored))}",
            file=sys.stderr,
        )
