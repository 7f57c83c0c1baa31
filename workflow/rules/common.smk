from mjtrial.layout import FIGURES, Layout
from mjtrial.provenance import model_sha256
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
