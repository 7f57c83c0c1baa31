"""The results' files: where each goes, how it is written, how a good one is kept.

- `layout`: every path under `results/<experiment>/`, and the pipeline's stages.
- `atomic`: atomic file output (a temporary file renamed onto the final name).
- `safekeeping`: the snapshot of the results before a run, put back where a job failed.
- `codehash`: the code a stage runs (its script and the package modules it imports), hashed
  for its outputs' stamps. Not in `provenance`, which imports no other part of the package.
- `schemas`: the JSON schemas shipped with the package, parsed once per process.
"""
