"""Compare two results folders of the same experiment, run on SLURM and locally.

Usage: python compare_results.py RESULTS_A RESULTS_B. Prints one line per difference and
exits 1 if there is any: the same set of files (logs aside), every Parquet table equal
(values and schema, its provenance metadata aside) and every JSON result equal but for its
`provenance` stamp (the summary, the nominal episodes). Other files (recordings, figures,
the report, the manifest, the seal, the crate) carry their run's stamp inside, so equal tables and
summary are what "the same results" means here.
"""

import json
import sys
from pathlib import Path

import pyarrow.parquet as pq

STAMP_KEY = "provenance"
# JSON files that hold results; the manifest, the seal and the crate record the run itself (its
# command, job times and the hashes of stamped files), so they differ between two runs; the
# registration and its deviations record when the design was registered (a time).
RUN_RECORDS = {
    "manifest.json",
    "seal.json",
    "ro-crate-metadata.json",
    "registration.json",
    "deviations.json",
}


def relative_files(root: Path) -> set[Path]:
    """Every file under `root`, relative to it, logs aside (they hold times and host names)."""
    return {
        path.relative_to(root)
        for path in root.rglob("*")
        if path.is_file() and "logs" not in path.relative_to(root).parts
    }


def differences(a: Path, b: Path) -> list[str]:
    """What differs between results folders `a` and `b`, one line each."""
    files_a, files_b = relative_files(a), relative_files(b)
    found = [f"only in {a}: {p}" for p in sorted(files_a - files_b)]
    found += [f"only in {b}: {p}" for p in sorted(files_b - files_a)]
    tables = sorted(p for p in files_a & files_b if p.suffix == ".parquet")
    for rel in tables:
        table_a = pq.read_table(a / rel).replace_schema_metadata(None)
        table_b = pq.read_table(b / rel).replace_schema_metadata(None)
        if not table_a.equals(table_b):
            found.append(f"table differs: {rel}")
    results = sorted(
        p for p in files_a & files_b if p.suffix == ".json" and p.name not in RUN_RECORDS
    )
    for rel in results:
        doc_a, doc_b = (json.loads((root / rel).read_text()) for root in (a, b))
        for doc in (doc_a, doc_b):  # a JSON list (the crate's copy of a source) has no stamp
            if isinstance(doc, dict):
                doc.pop(STAMP_KEY, None)
        if doc_a != doc_b:
            found.append(f"result differs: {rel}")
    if not tables:
        found.append(f"no Parquet table under {a}")
    print(f"compared {len(tables)} table(s) and {len(results)} JSON result(s)")
    return found


def main() -> int:
    a, b = (Path(arg) for arg in sys.argv[1:3])
    found = differences(a, b)
    for line in found:
        print(line)
    return 1 if found else 0


if __name__ == "__main__":
    sys.exit(main())
