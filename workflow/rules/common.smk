from pathlib import Path

from mjtrial.pipeline import config_slice, stage_code_hash

RESULTS = Path("results") / config["experiment"]
CONDITIONS = list(config["conditions"])


def rollout_slice(wildcards):
    """The config a condition's rollout depends on: its own protocol parameters only."""
    return config_slice("rollout", config, condition=wildcards.condition)


def model_sha256(wildcards=None):
    """Content of the model, so a checkout that only touches its mtime reruns nothing."""
    from mjtrial.provenance import model_sha256

    return model_sha256(config["model"])
