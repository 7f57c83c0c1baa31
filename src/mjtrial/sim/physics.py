"""MuJoCo's physics-state layout, a model's loading, and what a healthy episode is: the few
facts about a simulation that hold for every task.

An episode's trajectory is its `mjSTATE_FULLPHYSICS` vector at every physics step (time, qpos,
qvel, act, ...), shape `(n_steps, nstate)`; a batch stacks episodes in front.
"""

from __future__ import annotations

import ctypes
import functools
import hashlib
import os
from pathlib import Path

import mujoco
import numpy as np

from mjtrial.files.atomic import atomic_path
from mjtrial.sim.contacts import MIXED_GEOM_FIELDS, contact_digest_values

# Layout of an mjSTATE_FULLPHYSICS vector: time, qpos, qvel, act, ...
FULLPHYSICS = mujoco.mjtState.mjSTATE_FULLPHYSICS.value
"""The state signature of a physics state row (`mujoco.mj_getState`): time, qpos, qvel, act,
plugin state, mocap poses, equality flags; what `mujoco.rollout` returns per step."""
STATE_TIME = 0
"""The column of a physics state row holding the simulation time."""
STATE_QPOS = 1
"""The column of a physics state row where qpos begins (`row[STATE_QPOS:STATE_QPOS + nq]`)."""


class ModelError(ValueError):
    """A model file that cannot be used: missing, not compiling, or lacking what a task reads."""


def _one_line(err: Exception) -> str:
    """MuJoCo's message on one line (an XML error names its line on the second), quotes and the
    working folder dropped, so an error names a file as the user wrote it."""
    text = str(err).replace("'", "").replace(str(Path.cwd().resolve()) + "/", "")
    return " ".join(text.split()) or "compile error"


def load_spec(path: str | os.PathLike[str]) -> mujoco.MjSpec:
    """A model file's `MjSpec`, read from its absolute path; one line (`ModelError`) naming the
    file when it cannot be.

    Every model is read from its absolute path, in every stage: MuJoCo 3.14 resolves an include
    nested in an included file against the working folder when the main file's path is relative
    (`scene.xml` including `kinova/arm.xml` including `common.xml` looks for
    `kinova/kinova/common.xml`), so a relative path can fail where an absolute one compiles.
    """
    path = Path(path)
    if not path.is_file():
        raise ModelError(f"{path}: model file not found")
    try:
        return mujoco.MjSpec.from_file(str(path.resolve()))
    except ValueError as err:
        raise ModelError(f"{path}: MuJoCo could not read the model: {_one_line(err)}") from None


_KEEP_IN: list[Path] = []  # the folder `keep_compiled_models` named, in this process


def keep_compiled_models(folder: str | os.PathLike[str] | None) -> None:
    """Make `load_model` keep compiled models in `folder` in this process (None: no longer).
    The workflow's processes do (`layout.COMPILED_MODELS`): Snakemake's, which compiles the
    model first (the config check), and each job process, which reads it."""
    _KEEP_IN[:] = [] if folder is None else [Path(folder)]


def load_model(
    path: str | os.PathLike[str], *, compiled_in: str | os.PathLike[str] | None = None
) -> mujoco.MjModel:
    """Compile a model file, from its absolute path (`load_spec` says why); one line
    (`ModelError`) naming the file when it cannot be.

    `compiled_in`: a folder that keeps compiled models (`compiled_file`; by default the one
    `keep_compiled_models` named, if any), read from there when this model's files were
    compiled by this MuJoCo before, else kept there. A process that
    compiles robosuite's Panda scene (40 MB of OBJ meshes) holds 330 MB at its peak and takes 2 s;
    one that reads its MJB, 170 MB and 0.5 s. The MJB is MuJoCo's own copy of the compiled
    model, so the episodes are the same (`tests/test_physics.py`)."""
    path = Path(path)
    if not path.is_file():
        raise ModelError(f"{path}: model file not found")
    folder = compiled_in if compiled_in is not None else next(iter(_KEEP_IN), None)
    kept = None if folder is None else compiled_file(folder, path)
    if kept is not None and kept.is_file():
        try:
            return mujoco.MjModel.from_binary_path(str(kept))
        except ValueError:  # not a model this MuJoCo reads: compiled again below
            pass
    try:
        model = mujoco.MjModel.from_xml_path(str(path.resolve()))
    except ValueError as err:
        raise ModelError(f"{path}: MuJoCo could not compile the model: {_one_line(err)}") from None
    if kept is not None:
        try:
            with atomic_path(kept) as tmp:
                mujoco.mj_saveModel(model, str(tmp), None)
        except OSError:  # a folder that cannot keep it: the next process compiles too
            pass
        drop_asset_cache()  # the next load reads the kept model: the cache serves no compile
    return model


def compiled_file(folder: str | os.PathLike[str], path: str | os.PathLike[str]) -> Path:
    """Where `load_model` keeps a model compiled by this MuJoCo: named by the hash of every
    file the model reads (`provenance.model_sha256`) and MuJoCo's version, so an edited mesh
    or another MuJoCo (a variant's environment) never finds an old one."""
    from mjtrial.provenance import model_sha256  # the model's closure, which reads the XML

    return Path(folder) / f"{model_sha256(path)}.mujoco-{mujoco.__version__}.mjb"


def drop_asset_cache() -> None:
    """Empty MuJoCo's asset cache and hand the freed pages back. MuJoCo keeps every mesh and
    texture it decoded for the next compile in the process (up to 512 MB): worth it where
    models are compiled again, 110 MB held for nothing in a job process that compiled its
    model once (robosuite's exported Panda scene: a rollout job's memory 353 -> 243 MB after
    its model)."""
    mujoco.mj_clearCache(mujoco.mj_getCache())
    try:
        ctypes.CDLL("libc.so.6").malloc_trim(0)
    except (OSError, AttributeError):  # not glibc: the cache is freed all the same
        pass


def compiled_sha256(model: mujoco.MjModel) -> str:
    """The sha256 of a compiled model: its MJB bytes (`mj_saveModel`) with the asset files'
    paths blanked. A function of the model's files and edits alone (and of MuJoCo's version),
    the same in every process and folder.

    `MjSpec.to_xml()` is not: in MuJoCo 3.14 the first call in a process writes
    `content_type="model/stl"` on meshes and later calls do not. The MJB keeps, for an asset
    named in an included file, its absolute path (`model.paths`); the asset's content is in the
    MJB itself (vertices, texels), so the path adds nothing but the folder the files lie in.
    """
    # one buffer, blanked in place: a copy per step made robosuite's Panda scene (a 64 MB MJB) cost
    # Snakemake's process 190 MB more at its config check
    mjb = bytearray(mujoco.mj_sizeModel(model))
    mujoco.mj_saveModel(model, None, np.frombuffer(mjb, dtype=np.uint8))
    paths = bytes(model.paths)
    if paths.strip(b"\0"):
        at = mjb.find(paths)
        while at >= 0:
            mjb[at : at + len(paths)] = bytes(len(paths))
            at = mjb.find(paths, at + len(paths))
    return hashlib.sha256(mjb).hexdigest()


# Fields of a compiled model that no step, reset or sensor reads: how it looks (colours,
# materials, textures, lights, skins, the groups a viewer shows) and what things are called.
# The actuators' groups are read (`opt.disableactuator`), and so are cameras (a camera
# projection sensor): both stay. A field kept by mistake only lets an edit through as before.
_NOT_SIMULATED_PREFIXES = ("name_", "mat_", "tex_", "light_", "skin_")
_NOT_SIMULATED_MARKS = ("_rgba", "_matid", "_pathadr", "texcoord")
_NOT_SIMULATED = frozenset(
    {"names", "names_map", "paths", "geom_group", "site_group", "jnt_group", "tendon_group"}
    | {"flex_group"}
)


@functools.cache
def _simulated_fields(names: tuple[str, ...]) -> tuple[str, ...]:
    """The fields of `MjModel` (`dir` of one) kept, in order: the same for every model."""
    return tuple(
        name
        for name in sorted(names)
        if not name.startswith("_")
        and name not in _NOT_SIMULATED
        and not name.startswith(_NOT_SIMULATED_PREFIXES)
        and not any(mark in name for mark in _NOT_SIMULATED_MARKS)
    )


def simulated_sha256(model: mujoco.MjModel, state: np.ndarray) -> str:
    """The sha256 of what a simulation from `state` (an mjSTATE_FULLPHYSICS vector) under
    `model` depends on: equal hashes, the same simulation, so an edit or a state parameter
    whose hashes are equal changes nothing and is refused.

    Not a comparison of the model's bytes (`compiled_sha256`), which a colour, a name or a
    number MuJoCo ignores would change, nor a short simulation, which an edit that acts only
    later or elsewhere (a joint limit not reached, a contact not yet made) would pass as the
    same: every field of the model that can act on the physics, `opt` and the mean inertia the
    solver scales by, and the initial state. Left out are the fields listed above and those
    MuJoCo ignores for their element: a body whose joint is free is placed by its qpos alone,
    so its `body_pos` and `body_quat` are never read, and its qpos0 only by a reset, whose
    result `state` is (with a keyframe, qpos0 is not even that); a joint without a spring
    never reads its `qpos_spring` (which a free body's position sets too). A geom's friction,
    condim, priority, solmix, solref and solimp are read only to mix its pairs' contact
    parameters: the pairs that can touch and their mixed values are hashed instead
    (`contacts.contact_digest_values`), so a block's friction lowered under jaws that grip
    harder changes nothing (with flexes, which mix with geoms too, the geoms' own are hashed).
    """
    free = np.flatnonzero(model.jnt_type == mujoco.mjtJoint.mjJNT_FREE)
    unsprung = np.flatnonzero(
        (model.jnt_stiffness == 0) & (model.jnt_stiffnesspoly == 0).all(axis=-1)
    )
    widths = {int(mujoco.mjtJoint.mjJNT_FREE): 7, int(mujoco.mjtJoint.mjJNT_BALL): 4}
    unread = {  # qpos entries a field holds for joints that never read them
        "qpos0": free,  # a free joint's: a reset's alone (other joints' kinematics read theirs)
        "qpos_spring": unsprung,  # the rest position of a joint without a spring
    }
    mixed = () if model.nflex else MIXED_GEOM_FIELDS
    digest = hashlib.sha256()
    for name in _simulated_fields(tuple(dir(model))):
        value = getattr(model, name)
        if not isinstance(value, np.ndarray) or name in mixed:
            continue
        if free.size and name in ("body_pos", "body_quat"):
            value = value.copy()
            value[model.jnt_bodyid[free]] = 0
        elif name in unread and unread[name].size:
            value = value.copy()
            for joint in unread[name]:
                adr = model.jnt_qposadr[joint]
                value[adr : adr + widths.get(int(model.jnt_type[joint]), 1)] = 0
        digest.update(f"{name} {value.dtype.char} {value.shape}".encode())
        digest.update(np.ascontiguousarray(value).tobytes())
    for name in sorted(a for a in dir(model.opt) if not a.startswith("_")):
        digest.update(name.encode() + np.asarray(getattr(model.opt, name)).tobytes())
    if mixed:
        digest.update(b"contacts " + contact_digest_values(model).tobytes())
    digest.update(np.float64(model.stat.meaninertia).tobytes())
    digest.update(np.ascontiguousarray(state, dtype=np.float64).tobytes())
    return digest.hexdigest()


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
