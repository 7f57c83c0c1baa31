"""The results' files: where each goes, how it is written, how a good one is kept.

- `layout`: every path under `results/<experiment>/`, and the pipeline's stages.
- `atomic`: atomic file output (a temporary file renamed onto the final name).
- `safekeeping`: the snapshot of the results before a run, put back where a job failed.
"""
