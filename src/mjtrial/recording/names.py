"""Names in a recording: entity paths, series and property names, recording ids, file names.

Every one of them is spelled here, and the viewer's layout (`default_blueprint`) too.
"""

from __future__ import annotations

from collections.abc import Sequence

import mujoco
import numpy as np
import rerun as rr
import rerun.blueprint as rrb

APPLICATION_ID = "mjtrial"
TIMELINE = "sim_time"  # the one timeline: simulated seconds, stored as integer nanoseconds
PROPERTIES = "/" + rr.RECORDING_PROPERTIES_PATH.strip("/")  # entity of recording properties
WORLD = "world"  # entity of MuJoCo's world body: the root of the body tree

# Recording properties.
EPISODE_PROPERTY = "episode"
EPISODE_COMPONENT = "fields"  # the episode property's one component: a struct
PROVENANCE_PROPERTY = "provenance"
SOURCE_PROVENANCE_PROPERTY = "source_provenance"
FAILURES_PROPERTY = "failures"
JSON_FIELD = "json"  # the component of a property held as JSON text
# An episode recording whose meshes are in a mesh store (a recording of their own, once per
# folder or file) names it in this property: its recording id and the file in its folder.
MESHES_PROPERTY = "meshes"
MESH_STORE_FILE = "meshes.rrd"  # a condition's (shard's) folder's mesh store
MESH_STORE_PREFIX = "meshes-"  # a mesh store's recording id: this and its content's digest

FAILURES_SUMMARY = "failures"  # recording id and entity of failures.rrd's summary
FAILURE_PREFIX = "failures-"  # recording ids of episodes copied into failures.rrd
CLOSEST_CALLS_SUMMARY = "closest_calls"  # recording id and entity of closest_calls.rrd's table
CLOSEST_CALLS_PREFIX = "closest_calls-"  # recording ids of its episodes (after the summary)


def body_entity(model: mujoco.MjModel, body_id: int) -> str:
    """Entity path of a body: its parent's path, then its name (or ``body_<i>``).

    MuJoCo's world body is ``world``, so a hand on an arm is ``world/arm/hand``.
    """
    parts = []
    while body_id != 0:
        name = model.body(body_id).name or f"body_{body_id}"
        parts.append(rr.escape_entity_path_part(name))
        body_id = int(model.body_parentid[body_id])
    return "/".join([WORLD, *reversed(parts)])


def top_level_entity(body_name: str) -> str:
    """Entity path of a child of the world body, by its name (a free body)."""
    return f"{WORLD}/{rr.escape_entity_path_part(body_name)}"


def episode_recording_id(condition: str, state_id: int) -> str:
    """Deterministic recording id, so reruns of the same episode are comparable."""
    return f"{condition}-state-{int(state_id):06d}"


def episode_recording_name(condition: str, state_id: int) -> str:
    """Recording name shown in the viewer."""
    return f"{condition} / state {int(state_id)}"


def file_name(recording_id: str) -> str:
    """The file of a recording in its condition's folder: named by its recording id."""
    return f"{recording_id}.rrd"


def episode_file_name(condition: str, state_id: int) -> str:
    """The file of an episode's recording in its condition's folder."""
    return file_name(episode_recording_id(condition, state_id))


def logged_steps(nstep: int, log_every: int) -> np.ndarray:
    """Steps that are logged: every `log_every`-th (1-based), and always the last one."""
    if isinstance(log_every, bool) or not isinstance(log_every, (int, np.integer)):
        raise TypeError(f"log_every: expected an integer, got {log_every!r}")
    if log_every < 1:
        raise ValueError(f"log_every: expected >= 1, got {log_every}")
    if nstep < 1:
        raise ValueError(f"expected at least one step, got {nstep}")
    steps = np.arange(log_every - 1, nstep, log_every)
    if steps.size == 0 or steps[-1] != nstep - 1:
        steps = np.append(steps, nstep - 1)
    return steps


# Shapes drawn solid, as in MuJoCo's viewer. Set as defaults of the 3D view rather than logged
# with the shapes: a component logged costs every recording ~0.5 kB in the file's footer.
SOLID_SHAPES = (rr.Boxes3D, rr.Ellipsoids3D, rr.Capsules3D, rr.Cylinders3D)


def default_blueprint(plots: Sequence[tuple[str, Sequence[str]]]) -> rrb.Blueprint:
    """Viewer layout: the scene on the left, the task's plots of its series on the right.

    Args:
      plots: (title, entities) of each plot, top to bottom: a plot shows the series of its
        entities (`series.plots`). The scene's view draws shapes solid (rerun's default for
        boxes is a wireframe).
    """
    solid = [shape.from_fields(fill_mode=rr.components.FillMode.Solid) for shape in SOLID_SHAPES]
    return rrb.Blueprint(
        rrb.Horizontal(
            rrb.Spatial3DView(origin=WORLD, name="scene", defaults=solid),
            rrb.Vertical(
                *(
                    rrb.TimeSeriesView(
                        origin=WORLD,
                        contents=[f"+ /{e.strip('/')}" for e in entities],
                        name=title,
                    )
                    for title, entities in plots
                )
            ),
            column_shares=[3, 2],
        )
    )
