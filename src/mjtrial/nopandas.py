"""pyarrow without pandas in a job's process that holds no pandas object: a rollout job.

pyarrow imports pandas at its first conversion of a numpy array or a list (to check for pandas
types: a categorical, a time zone) and at its first conversion to numpy (its C++ converter's
static data): about 0.3 s of CPU, more than the rest of a shard's setup, for a module the job
never uses. Each side tries the import once and, refused then, takes pandas as absent; its
conversions of numpy arrays and lists are the same either way, and a later call that needs
pandas (`Table.to_pandas`) imports it then.
"""

from __future__ import annotations

import sys

import numpy as np
import pyarrow as pa


class _Refuse:
    """A finder (`sys.meta_path`) that refuses pandas and leaves every other module alone."""

    def find_spec(self, name: str, path: object = None, target: object = None) -> None:
        if name == "pandas":
            raise ImportError("pandas: not imported by this job (mjtrial.nopandas)")
        return None


def pyarrow_without_pandas() -> None:
    """Have pyarrow take pandas as absent in this process, unless pandas is imported already
    (then nothing changes)."""
    if "pandas" in sys.modules:
        return
    refuse = _Refuse()
    sys.meta_path.insert(0, refuse)
    try:
        pa.array(np.zeros(1)).to_numpy()  # the Cython shim's try, then the C++ converter's
        pa.array([0.0])
    finally:
        sys.meta_path.remove(refuse)
