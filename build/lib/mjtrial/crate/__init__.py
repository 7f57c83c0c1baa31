"""A results folder as a Provenance Run Crate: the RO-Crate every run ends with.

`ro-crate-metadata.json` in a results folder describes, with the `rocrate` library, every run
sealed there (the built-in experiment and each study): the workflow, its stages as tools and
steps, one action per job with its inputs, config slice, outputs and times, the library
versions, and every file with its sha256 and size (`mjtrial.crate.graph`). The crate job
copies the workflow's sources beside it (`source/`, `mjtrial.crate.sources`), so the folder is
a crate whose workflow is one of its files. `mjtrial verify` rebuilds the crate from the folder
and compares (`mjtrial.verify`); `mjtrial crate --zip` packs the folder with its sources into an
archive that is a checkout and a crate at once (`mjtrial.crate.archive`).

Importing this package lets `mjtrial.provenance.read_stamp` read the crate's stamp
(`mjtrial.crate.stamp`).
"""

from mjtrial.crate.stamp import STAMP_ID, read_crate_stamp, register_readers

register_readers()

__all__ = ["STAMP_ID", "read_crate_stamp", "register_readers"]
