"""MuJoCo's physics-state layout, a model's loading, and what a healthy episode is: the few
facts about a simulation that hold for every task.

An episode's trajectory is its `mjSTATE_FULLPHYSICS` vector at every physics step (time, qpos,
qvel, act, ...), shape `(n_steps, nstate)`; a batch stacks episodes in front.
"""

from __future__ import annotations

from pathlib import Path

import mujoco
import numpy as np

# Layout of an mjSTATE_FULLPHYSICS vector: time, qpos, qvel, act, ...
FULLPHYSICS = mujoco.mjtState.mjSTATE_FULLPHYSICS.value
STATE_TIME = 0
STATE_QPOS = 1


class ModelError(ValueError):
    """A model file that cannot be used: missing, not compiling, or lacking what a task reads."""


def load_model(path: str | Path) -> mujoco.MjModel:
    """Compile a model file; one line (`ModelError`) naming the file when it cannot be."""
    path = Path(path)
    if not path.is_file():
        raise ModelError(f"{path}: model file not found")
    try:
        model = mujoco.MjModel.from_xml_path(str(path))
    except ValueError as err:
        # MuJoCo's message spans lines (an XML error names its line on the second): one line.
        message = " ".join(str(err).replace("'", "").split()) or "compile error"
        raise ModelError(f"{path}: MuJoCo could not compile the model: {message}") from None
    return model


def halted(physics: np.ndarray) -> np.ndarray:
    """Where an episode stopped early, from its physics states `(..., n_steps, nstate)`.

    `mujoco.rollout` stops stepping at a MuJoCo warning and repeats the last state (a bad
    acceleration resets it first), so time is not a step counter: a repeated time is the halt.
    Returns `(...)` booleans.
    """
    return (np.diff(physics[..., STATE_TIME], axis=-1) == 0).any(axis=-1)


def steps_simulated(physics: np.ndarray) -> np.ndarray:
    """Steps an episode ran before it halted (all of them if it did not), shape `(...)`."""
    frozen = np.diff(physics[..., STATE_TIME], axis=-1) == 0
    n_steps = physics.shape[-2]
    return np.where(frozen.any(axis=-1), frozen.argmax(axis=-1) + 1, n_steps).astype(np.int64)


def nonfinite(physics: np.ndarray) -> np.ndarray:
    """Where an episode's state went NaN or infinite at any step, shape `(...)`."""
    return ~np.isfinite(physics).all(axis=(-2, -1))


def healthy(physics: np.ndarray) -> np.ndarray:
    """An episode is healthy when it ran to the end with a finite state: `(...)` booleans."""
    return ~halted(physics) & ~nonfinite(physics)
