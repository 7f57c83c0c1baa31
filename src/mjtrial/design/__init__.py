"""The experiment's design: what runs, on which initial states, as registered.

- `conditions`: the conditions an experiment runs (the design's own, a sweep's), their model
  edits and policies.
- `states`: the initial states, drawn once from a seeded generator.
- `registration`: the registered design, its deviations, its history.
"""
