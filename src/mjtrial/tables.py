"""Reading a Parquet table the light way.

`pyarrow.parquet.read_table` goes through `pyarrow.dataset`, which imports pandas: 54 MB that
would then stay in Snakemake's process for the rest of the run (it runs the light jobs), and
in every job process. One file needs none of it.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import pyarrow as pa
import pyarrow.parquet as pq


def read_table(path: str | Path, columns: Sequence[str] | None = None) -> pa.Table:
    """The table of one Parquet file (its schema's metadata included), or only `columns`."""
    with pq.ParquetFile(path) as f:
        return f.read(columns=None if columns is None else list(columns))
