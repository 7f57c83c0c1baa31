"""The rollout of one condition on a simulator variant: the model edited through `MjSpec`."""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np

from mjtrial import REPO_ROOT
from mjtrial.stages.rollout import run_condition
from mjtrial.studies.variants import variant_model


def run_variant_condition(
    *,
    variant_slice: Mapping[str, Any],
    model_file: Path,
    repo_root: Path = REPO_ROOT,
    **outputs_and_inputs: Any,
) -> dict[str, np.ndarray]:
    """`run_condition` on the variant named in `variant_slice["variant"]`.

    The stamp's rule is `rollout_variant:<variant>/<condition>`; its config slice holds the
    variant's overrides, so an edited variant reruns its own episodes only.
    """
    variant = variant_slice["variant"]
    model, _ = variant_model(
        model_file, variant["overrides"], key_prefix=f"variants.{variant['name']}"
    )
    return run_condition(
        condition_slice=variant_slice,
        model_file=model_file,
        model=model,
        rule=f"rollout_variant:{variant['name']}/{variant_slice['condition']}",
        repo_root=repo_root,
        **outputs_and_inputs,
    )
