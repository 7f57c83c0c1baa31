"""A table's own hash in its stamp: a rollout shard is the root of every number built on it,
so its stamp records the sha256 of its rows (`ROWS_KEY` under `extra`), and every reader of
a shard refuses one whose rows are no longer those (`read_checked_table`). A seal records a
file's bytes; this records the data, so an edited row is named even after the seal, the
condition's table and the analysis were rebuilt over it.
"""

from __future__ import annotations

import hashlib
import json
import os
from typing import TYPE_CHECKING, Any

from mjtrial.provenance.formats import read_stamp

if TYPE_CHECKING:  # pragma: no cover
    import pyarrow

__all__ = ["ROWS_KEY", "RowsMismatchError", "read_checked_table", "rows_problem", "rows_sha256"]

ROWS_KEY = "rows_sha256"


class RowsMismatchError(ValueError):
    """A table whose rows are not the ones its stamp records (one line naming the file)."""


def rows_sha256(table: pyarrow.Table) -> str:
    """sha256 of a table's rows: each column's name, type, nulls and values, whatever the
    chunks and encodings that hold them (the table a job holds and the one read back from its
    Parquet file hash alike; NaNs as one NaN). Hashes the arrays in memory: no file is read."""
    # slow imports (pyarrow ~0.2 s): only what hashes a table pays them, as `write_parquet`
    import numpy as np
    import pyarrow as pa
    import pyarrow.compute as pc

    digest = hashlib.sha256()
    for name, column in zip(table.column_names, table.columns, strict=True):
        digest.update(f"{name}\0{column.type}\0{len(column)}\n".encode())
        digest.update(np.packbits(column.is_valid().to_numpy()).tobytes())
        kind = column.type
        if pa.types.is_integer(kind) or pa.types.is_floating(kind) or pa.types.is_boolean(kind):
            values = np.asarray(pc.fill_null(column, False if pa.types.is_boolean(kind) else 0))
            if values.dtype.kind == "f":
                values = np.where(np.isnan(values), np.nan, values)
            digest.update(np.ascontiguousarray(values).tobytes())
        else:
            digest.update(json.dumps(column.to_pylist(), default=str).encode())
    return digest.hexdigest()


def _recorded(stamp: Any) -> str | None:
    extra = stamp.get("extra") if isinstance(stamp, dict) else None
    value = extra.get(ROWS_KEY) if isinstance(extra, dict) else None
    return value if isinstance(value, str) else None


_MISMATCH = (
    f"its rows are not the ones its stamp records ({ROWS_KEY}): it was edited after its job "
    "wrote it; delete it and rerun `snakemake -c2` to rebuild it"
)


def read_checked_table(path: str | os.PathLike[str]) -> pyarrow.Table:
    """The Parquet table at `path` (its stamp in its schema metadata), refused in one line
    (`RowsMismatchError`) when its stamp records the sha256 of its rows and they differ."""
    import pyarrow.parquet as pq  # slow import, see rows_sha256

    table = pq.read_table(path)
    recorded = _recorded(read_stamp(path))
    if recorded is not None and rows_sha256(table.replace_schema_metadata(None)) != recorded:
        raise RowsMismatchError(f"{path}: {_MISMATCH}")
    return table


def rows_problem(path: str | os.PathLike[str]) -> str | None:
    """Why the table at `path` is not what its stamp records of its rows, or None (its rows
    are, or its stamp records none: a table no rollout wrote)."""
    try:
        read_checked_table(path)
    except RowsMismatchError:
        return _MISMATCH
    except (OSError, ValueError):
        return None  # unreadable or unstamped: what reads it says so
    return None
