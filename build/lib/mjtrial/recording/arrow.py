"""rerun's internal chunk encoding: the one module of the package that relies on it.

The recordings are built straight from Arrow columns (``Chunk.from_record_batch``) and read
back from a chunk's record batch, which is much faster than logging through a
``RecordingStream``. That leans on how rerun encodes a chunk as Arrow, which is not a stable
API: the metadata keys ``rerun:entity_path``, ``rerun:kind`` and ``rerun:component``, column
names of the form ``<Archetype>:<field>``, and the types of the components. All of it lives
here, and importing this module checks that rerun-sdk is the version it was written for.
"""

from __future__ import annotations

import functools
from collections.abc import Iterable, Iterator, Mapping, Sequence
from contextlib import contextmanager
from typing import Any

import numpy as np
import pyarrow as pa
import rerun as rr
from rerun.chunk import Chunk
from rerun.error_utils import catch_and_log_exceptions

from mjtrial.recording.names import PROPERTIES, TIMELINE

WRITTEN_FOR_RERUN = "0.41.0"


def check_rerun_version(version: str) -> None:
    """Raise unless `version` is the rerun-sdk this encoding was written for."""
    if version != WRITTEN_FOR_RERUN:
        raise RuntimeError(
            f"mjtrial.recording was written for rerun-sdk {WRITTEN_FOR_RERUN}, found {version}: "
            f"its chunk encoding (mjtrial/recording/arrow.py) must be checked against that "
            f"version before recordings are written or read"
        )


check_rerun_version(rr.__version__)

# Column names of components in a chunk's record batch.
TRANSLATION = "Transform3D:translation"
QUATERNION = "Transform3D:quaternion"
SCALARS = "Scalars:scalars"
SERIES_NAMES = "SeriesLines:names"
RECORDING_NAME = "RecordingInfo:name"

TIME_FIELD = pa.field(TIMELINE, pa.duration("ns"))  # the timeline's column

_ENTITY_KEY = b"rerun:entity_path"
_KIND_KEY = b"rerun:kind"
_COMPONENT_KEY = b"rerun:component"
_DATA = b"data"

Column = tuple[pa.Field, pa.Array]  # a component column tagged with its entity (`tag`)


@contextmanager
def strict() -> Iterator[None]:
    """Make rerun raise on misuse inside this block instead of warning and dropping data."""
    with catch_and_log_exceptions(context="mjtrial.recording", strict=True):
        yield


def tag(field: pa.Field, entity: str) -> pa.Field:
    """`field` tagged with its entity, so one record batch can describe several entities.

    `Chunk.from_record_batch` makes one chunk per entity of a batch.
    """
    entity = "/" + entity.lstrip("/")
    metadata = {**(field.metadata or {}), _ENTITY_KEY: entity.encode()}
    return pa.field(f"{entity}:{field.name}", field.type, metadata=metadata)


def data_columns(batch: pa.RecordBatch) -> Iterator[tuple[pa.Field, pa.Array]]:
    """The component columns of a chunk's record batch (not its row ids or times)."""
    for field, column in zip(batch.schema, batch.columns, strict=True):
        if (field.metadata or {}).get(_KIND_KEY) == _DATA:
            yield field, column


def column(batch: pa.RecordBatch, name: str) -> pa.Array:
    """The column `name` (a component or timeline) of a chunk's record batch."""
    return batch.column(batch.schema.names.index(name))


def archetype_columns(entity: str, archetypes: Iterable[Any]) -> list[Column]:
    """One static row holding all components of `archetypes`, as `rec.log(static=True)` would."""
    batches = []
    with strict():
        for archetype in archetypes:
            for batch in archetype.as_component_batches():
                batches.append(batch.partition([len(batch.as_arrow_array())]))
        record = Chunk.from_columns(entity, [], batches).to_record_batch()
    return [(tag(field, entity), values) for field, values in data_columns(record)]


def record_batch(columns: Sequence[Column]) -> pa.RecordBatch:
    fields, arrays = zip(*columns, strict=True)
    return pa.RecordBatch.from_arrays(list(arrays), schema=pa.schema(list(fields)))


def chunks(columns: Sequence[Column] | pa.RecordBatch, *, temporal: bool = False) -> list[Chunk]:
    """Chunks (fresh ids, one per entity) of columns; temporal ones are indexed by `TIMELINE`."""
    batch = columns if isinstance(columns, pa.RecordBatch) else record_batch(columns)
    with strict():
        return Chunk.from_record_batch(batch, index=TIMELINE if temporal else None)


@functools.cache
def series_fields() -> dict[str, pa.Field]:
    """Arrow field (type and rerun metadata) of each time-series component, as rerun builds it.

    Keys: `TRANSLATION`, `QUATERNION`, `SCALARS` (and the timeline's).
    """
    times = [rr.TimeColumn(TIMELINE, duration=np.zeros(1, dtype="timedelta64[ns]"))]
    with strict():
        columns = [
            *rr.Transform3D.columns(translation=np.zeros((1, 3)), quaternion=[[0, 0, 0, 1.0]]),
            *rr.Scalars.columns(scalars=np.zeros(1)),
        ]
        record = Chunk.from_columns("template", times, columns).to_record_batch()
    return {field.name: field for field in record.schema}


def property_columns(name: str, fields: Mapping[str, Any]) -> list[Column]:
    """The columns `rr.send_property(name, rr.AnyValues(**fields))` logs, built directly."""
    entity = f"{PROPERTIES}/{rr.escape_entity_path_part(name)}"
    out = []
    for key, value in fields.items():
        if isinstance(value, (bool, np.bool_)):
            arrow_type: pa.DataType = pa.bool_()
        elif isinstance(value, (int, np.integer)):
            arrow_type = pa.int64()
        elif isinstance(value, (float, np.floating)):
            arrow_type = pa.float64()
        elif isinstance(value, str):
            arrow_type = pa.string()
        else:
            raise TypeError(f"property {name}.{key}: unsupported value {value!r}")
        field = component_field(key, arrow_type, entity)
        out.append((field, pa.array([[value]], type=field.type)))
    return out


def component_field(component: str, value_type: pa.DataType, entity: str) -> pa.Field:
    """The field of a component of `entity` holding one `value_type` value per row."""
    metadata = {_KIND_KEY: _DATA, _COMPONENT_KEY: component.encode()}
    return tag(pa.field(component, pa.list_(value_type), metadata=metadata), entity)


@functools.cache
def recording_name_field() -> pa.Field:
    """The field of a recording's name (`rr.archetypes.RecordingInfo`)."""
    (field, _), *_ = archetype_columns(PROPERTIES, [rr.archetypes.RecordingInfo(name="")])
    return field
