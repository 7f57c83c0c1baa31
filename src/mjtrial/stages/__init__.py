"""One module per pipeline stage: what a Snakemake script calls, importable and testable.

Each stage reads its inputs, computes, and writes its outputs atomically with a provenance
stamp; none of them knows about Snakemake. A stage module imports only what its stage runs,
because its imports define its code hash (`mjtrial.files.codehash`).
"""
