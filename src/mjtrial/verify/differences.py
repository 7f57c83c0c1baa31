"""How an output differs from its recomputation: a JSON result key by key, a Markdown text line
by line, a table column by column (NaN equal to NaN), each as one short reason."""

from __future__ import annotations

import json
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow as pa

from mjtrial import provenance
from mjtrial.verify.chain import dict_diff

# How many differing keys, lines or rows a reason names.
SHOWN = 3


def _json_payload(path: Path) -> dict[str, Any]:
    obj = json.loads(provenance.read_output_text(path))
    return {k: v for k, v in obj.items() if k != "provenance"}


def _roundtrip(obj: Any) -> Any:
    """`obj` as JSON gives it back (tuples as lists, numpy scalars as numbers)."""
    return json.loads(json.dumps(obj, default=lambda v: v.item()))


def json_difference(path: Path, expected: Mapping[str, Any]) -> str | None:
    """Why a JSON output is not `expected` (its stamp aside), or None."""
    have, want = _json_payload(path), _roundtrip(dict(expected))
    if json.dumps(have, sort_keys=True) == json.dumps(want, sort_keys=True):
        return None
    diff = dict_diff(have, want) or ["(in a value that compares equal)"]
    more = f" and {len(diff) - SHOWN} more" if len(diff) > SHOWN else ""
    return f"{'; '.join(diff[:SHOWN])}{more} (file -> recomputed)"


def markdown_difference(path: Path, expected: str) -> str | None:
    """Why a Markdown output's text is not `expected` (its front matter aside), or None."""
    _, body = provenance.formats._split_front_matter(provenance.read_output_text(path))
    if body == expected:
        return None
    have, want = body.splitlines(), expected.splitlines()
    for i in range(max(len(have), len(want))):
        a = have[i] if i < len(have) else "(end of file)"
        b = want[i] if i < len(want) else "(end of text)"
        if a != b:
            return f"line {i + 1}: {a[:60]!r} in the file, {b[:60]!r} recomputed"
    return "differs in line endings"


def _column_equal(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Element-wise equality, NaN equal to NaN and None to None."""
    if a.dtype.kind == "f" and b.dtype.kind == "f":
        return (a == b) | (np.isnan(a) & np.isnan(b))
    return np.array([x == y for x, y in zip(a.tolist(), b.tolist(), strict=True)], dtype=bool)


def table_difference(
    table: pa.Table, expected: Mapping[str, np.ndarray], *, what: str = "rows"
) -> str | None:
    """Why `table`'s rows are not `expected` (column -> values, state ids aligned), or None."""
    if table.num_rows != len(next(iter(expected.values()))):
        return f"{table.num_rows} rows, {len(next(iter(expected.values())))} recomputed"
    bad_rows = np.zeros(table.num_rows, dtype=bool)
    bad_columns = []
    for name, values in expected.items():
        if name not in table.column_names:
            return f"no column {name!r}"
        have = table.column(name).to_numpy(zero_copy_only=False)
        unequal = ~_column_equal(have, np.asarray(values))
        if unequal.any():
            bad_columns.append(name)
            bad_rows |= unequal
    if not bad_columns:
        return None
    ids = table.column("state_id").to_numpy()[bad_rows].tolist()
    shown = ", ".join(map(str, ids[:SHOWN])) + (
        f" and {len(ids) - SHOWN} more" if len(ids) > SHOWN else ""
    )
    return f"{what} for states {shown} differ in {', '.join(bad_columns)}"


def columns(table: pa.Table) -> dict[str, np.ndarray]:
    """A table's columns by name, as `table_difference` takes its expectation."""
    return {c: table.column(c).to_numpy(zero_copy_only=False) for c in table.column_names}


def recomputed_difference(first: Any, second: Any, *, what: str) -> str | None:
    """Why two recomputations of one output (tables, or JSON records) differ, or None."""
    if isinstance(first, pa.Table):
        return table_difference(first, columns(second), what=what)
    as_json = [json.dumps(x, sort_keys=True, default=str) for x in (first, second)]
    return None if as_json[0] == as_json[1] else f"{what} of the nominal episode differ"


def not_reproduced(why: str, between: str) -> str:
    """Why an output is irreproducible: it differs from its re-simulation (`why`), and a
    second re-simulation differs from the first (`between`)."""
    return (
        f"differs from its re-simulation ({why}), and re-simulated twice here the two "
        f"disagree ({between}): the task's code is not a function of its arguments (its "
        "episode_setup, policy or a Custom state parameter draws unseeded randomness or reads "
        "module state, call order or the clock): no run of it can be reproduced; no sign of "
        "tampering"
    )
