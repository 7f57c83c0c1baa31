"""Rerun recordings of episodes: the one package that talks to rerun.

Why rerun: an episode's outcome is a handful of numbers, but *why* an episode failed is only
visible in its motion. Every condition gets a folder holding one ``.rrd`` per episode (one
recording each) and a ``blueprint.rbl``; the failed episodes of all conditions are gathered
into one ``failures.rrd``.

Layout of a recording (names in :mod:`~mjtrial.recording.names`):

* ``world``: view coordinates (z up) and the geoms of MuJoCo's world body (the floor), static.
* ``world/<body>``, nested as MuJoCo's body tree (``world/arm/hand``): the body's
  pose *in its parent body* per logged step (``Transform3D``; a body without joints gets it
  once, static) and, static, its visible geoms: one archetype per geom type (``Boxes3D`` for
  boxes and planes, ``Ellipsoids3D`` for spheres and ellipsoids, ``Capsules3D``,
  ``Cylinders3D``, one ``Mesh3D`` for all its meshes) whose instances are the geoms, each posed
  in the body frame and drawn in MuJoCo's colour (:mod:`~mjtrial.recording.scene`). In a
  condition's folder the meshes are not in the episodes' recordings: its ``meshes.rrd``
  holds them once (a mesh store, named by each recording's ``meshes`` property;
  `read.recording_chunks` puts them back). Visible sites are drawn as geoms are.
* the signals (``Scalars``), on the entity of the body they belong to, named by a static
  ``SeriesLines``: the task's series (`mjtrial.task.Series`), each on the body it names.
* recording properties ``episode`` (one struct: condition, state id and parameters, success,
  the task's recorded measures, failure category or null, ``log_every``, ``n_steps``) and
  ``provenance`` (the stamp as JSON, see :mod:`mjtrial.provenance`).

Time series use one timeline, ``sim_time``: simulated seconds, stored by rerun as integer
nanoseconds. `names.default_blueprint` lays out the scene beside one plot per title of the task's
series: a condition's folder holds it as ``blueprint.rbl``; ``failures.rrd`` and
a replay's file hold it themselves.

Modules: `names` (names, blueprint), `scene` (geoms, body poses), `series` (an episode's time
series), `arrow` (rerun's chunk encoding, checked against the rerun-sdk version), `write` (a
condition's folder, an episode's file), `route` (several streams in one file), `failures`
(``failures.rrd``), `read` (reading back). Importing the package registers the ``.rrd`` reader
of provenance stamps.
"""

from mjtrial import provenance
from mjtrial.recording.failures import write_failures_rrd, write_whole_episode
from mjtrial.recording.names import episode_file_name, logged_steps
from mjtrial.recording.read import (
    find_episode_file,
    list_recordings,
    read_episode,
    read_rrd_stamp,
    recording_files,
)
from mjtrial.recording.scene import mujoco_to_rerun_quat, rerun_to_mujoco_quat
from mjtrial.recording.write import (
    EpisodeRecord,
    write_condition_recordings,
    write_episode_recording,
)

__all__ = [
    "find_episode_file",
    "EpisodeRecord",
    "episode_file_name",
    "list_recordings",
    "logged_steps",
    "mujoco_to_rerun_quat",
    "read_episode",
    "read_rrd_stamp",
    "recording_files",
    "rerun_to_mujoco_quat",
    "write_condition_recordings",
    "write_episode_recording",
    "write_failures_rrd",
    "write_whole_episode",
]

provenance.register_reader(".rrd", read_rrd_stamp)
