"""An episode's time series as Arrow columns: the bodies' poses and the task's signals.

Everything runs once over the logged rows of many episodes: numpy's and pyarrow's cost per
call, not per row, dominates at a few hundred rows.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import NamedTuple

import mujoco
import numpy as np
import pyarrow as pa
import rerun as rr

from mjtrial.recording.arrow import (
    QUATERNION,
    SCALARS,
    TIME_FIELD,
    TRANSLATION,
    Column,
    archetype_columns,
    record_batch,
    series_fields,
    strict,
    tag,
)
from mjtrial.recording.names import body_entity
from mjtrial.recording.scene import BodyPoses, mujoco_to_rerun_quat, static_scene
from mjtrial.sim.physics import FULLPHYSICS, STATE_QPOS, STATE_TIME


class Signal(NamedTuple):
    """A logged time series: its name, the body whose entity holds it, the plot it is drawn in,
    and `read(rows, sensors, ctrl)` giving its values at logged rows (n,) from the physics
    (n, nstate), the sensors (n, nsensordata) and the ctrl (n, nu) there."""

    name: str
    body: int
    plot: str
    read: Callable[[np.ndarray, np.ndarray, np.ndarray], np.ndarray]


# (entity, series names, their columns in the signals) of an entity holding signals
Signals = tuple[str, tuple[str, ...], tuple[int, ...]]


def _grouped(model: mujoco.MjModel, signals: Sequence[Signal]) -> tuple[Signals, ...]:
    """Where each signal is logged: on the entity of the body it belongs to, in body order, so
    signals of one body share its time-series chunk."""
    columns: dict[str, list[int]] = {}
    for column, body in sorted(enumerate(s.body for s in signals), key=lambda c: c[1]):
        columns.setdefault(body_entity(model, body), []).append(column)
    return tuple((e, tuple(signals[c].name for c in cs), tuple(cs)) for e, cs in columns.items())


def plots(signals: Sequence[Signal], grouped: Sequence[Signals]) -> list[tuple[str, list[str]]]:
    """(plot title, the entities it shows) in order of the plots' first signal."""
    out: dict[str, list[str]] = {}
    for signal in signals:
        out.setdefault(signal.plot, [])
    for entity, _, columns in grouped:
        for plot in dict.fromkeys(signals[c].plot for c in columns):
            out[plot].append(entity)
    return list(out.items())


class Chunker:
    """A model's recordings as Arrow columns, built fast: the column layouts are prepared once.

    `geometry` and `styles` are the static columns every recording shares (geoms, static poses,
    series names; `geometry` without the meshes when `meshes` is False); `series` builds the
    time series of many episodes at once.
    """

    def __init__(
        self,
        model: mujoco.MjModel,
        signals: Sequence[Signal],
        *,
        meshes: bool = True,
        moving_mocap: bool = False,
    ) -> None:
        self.signal_reads = [s.read for s in signals]
        self.nstate = mujoco.mj_stateSize(model, FULLPHYSICS)
        self.nsensordata, self.nu, self.nq = model.nsensordata, model.nu, model.nq
        self.signals = _grouped(model, signals)
        self.plots = plots(signals, self.signals)
        self.poses = BodyPoses(model)
        scene = static_scene(model, meshes=meshes, moving_mocap=moving_mocap)
        self.geometry = [c for e, a in scene for c in archetype_columns(e, a)]
        with strict():
            styles = [(e, [rr.SeriesLines(names=list(names))]) for e, names, _ in self.signals]
        self.styles = [c for e, a in styles for c in archetype_columns(e, a)]
        fields = series_fields()
        self._pose_fields = [
            (tag(fields[TRANSLATION], m.entity), tag(fields[QUATERNION], m.entity))
            for m in self.poses.moving
        ]
        self._signal_fields = [tag(fields[SCALARS], e) for e, _, _ in self.signals]
        # (mocap index, its fields) of each mocap body a policy moves: its target per step
        mocap_bodies = np.flatnonzero(model.body_mocapid >= 0) if moving_mocap else []
        self._mocap_fields = [
            (
                int(model.body_mocapid[b]),
                tag(fields[TRANSLATION], body_entity(model, b)),
                tag(fields[QUATERNION], body_entity(model, b)),
            )
            for b in mocap_bodies
        ]
        self._offsets: dict[tuple[int, int], pa.Array] = {}

    def _list_offsets(self, n: int, width: int) -> pa.Array:
        key = (n, width)
        if key not in self._offsets:
            self._offsets[key] = pa.array(np.arange(0, n * width + 1, width, dtype=np.int32))
        return self._offsets[key]

    def _list(self, field: pa.Field, values: np.ndarray) -> pa.Array:
        """(n, width) values as a list column of `field`'s type: one row of `width` per step."""
        n, width = values.shape
        item = field.type.value_type
        if pa.types.is_fixed_size_list(item):
            dtype = item.value_type.to_pandas_dtype()
            flat = pa.array(np.ascontiguousarray(values, dtype=dtype).ravel())
            inner = pa.FixedSizeListArray.from_arrays(flat, type=item)
            return pa.ListArray.from_arrays(self._list_offsets(n, 1), inner, type=field.type)
        flat = pa.array(np.ascontiguousarray(values, dtype=np.float64).ravel())
        return pa.ListArray.from_arrays(self._list_offsets(n, width), flat, type=field.type)

    def series(
        self,
        episodes: Sequence[tuple[np.ndarray, np.ndarray, np.ndarray]],
        mocap: Sequence[np.ndarray] | None = None,
    ) -> pa.RecordBatch:
        """Time series of episodes, from each one's logged rows of physics, sensors and ctrl.

        Args:
          episodes: (rows, sensors, ctrl) per episode: (n, nstate) physics, (n, nsensordata)
            sensors and (n, nu) ctrl at the n logged steps, the same n for all.
          mocap: per episode, (n, nmocap, 7) the mocap targets during the logged steps (pos,
            quat w-x-y-z), for a chunker of `moving_mocap`; drawn as MuJoCo places the body
            (its quaternion normalized).

        Returns:
          the columns of all episodes, one after another: episode i's are rows i*n to (i+1)*n
          (zero-copy slices). A moving body's pose is in its parent body, whose entity holds
          the parent's pose; the time is `physics[:, 0]` in integer nanoseconds.
        """
        rows = np.concatenate([r for r, _, _ in episodes])
        sensors = np.concatenate([s for _, s, _ in episodes])
        ctrl = np.concatenate([c for _, _, c in episodes])
        time_ns = np.rint(rows[:, STATE_TIME] * 1e9).astype(np.int64).astype("timedelta64[ns]")
        columns: list[Column] = [(TIME_FIELD, pa.array(time_ns))]
        poses = self.poses(rows[:, STATE_QPOS : STATE_QPOS + self.nq])
        for (pos, quat), (t_field, q_field) in zip(poses, self._pose_fields, strict=True):
            columns.append((t_field, self._list(t_field, pos)))
            if quat is not None:
                columns.append((q_field, self._list(q_field, mujoco_to_rerun_quat(quat))))
        if self._mocap_fields:
            targets = np.concatenate(list(mocap))
            for index, t_field, q_field in self._mocap_fields:
                quat = targets[:, index, 3:]
                quat = quat / np.linalg.norm(quat, axis=1, keepdims=True)
                columns.append((t_field, self._list(t_field, targets[:, index, :3])))
                columns.append((q_field, self._list(q_field, mujoco_to_rerun_quat(quat))))
        signals = np.empty((len(rows), len(self.signal_reads)))
        for i, read in enumerate(self.signal_reads):
            signals[:, i] = read(rows, sensors, ctrl)
        for field, (_, _, indices) in zip(self._signal_fields, self.signals, strict=True):
            columns.append((field, self._list(field, signals[:, list(indices)])))
        return record_batch(columns)

    def trajectory(
        self, physics: np.ndarray, sensordata: np.ndarray, ctrl: np.ndarray, *, n_steps: int
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """An episode's arrays as float64, checked: `(n_steps, nstate)`, `(n_steps,
        nsensordata)` and `(n_steps, nu)`."""
        ctrl = np.asarray(ctrl, dtype=np.float64)
        physics = np.asarray(physics, dtype=np.float64)
        sensordata = np.asarray(sensordata, dtype=np.float64)
        expected = {
            "ctrl": (ctrl, (n_steps, self.nu)),
            "physics": (physics, (n_steps, self.nstate)),
            "sensordata": (sensordata, (n_steps, self.nsensordata)),
        }
        for name, (array, shape) in expected.items():
            if n_steps < 1 or array.shape != shape:
                raise ValueError(f"{name}: expected shape {shape}, got {array.shape}")
        return physics, sensordata, ctrl
