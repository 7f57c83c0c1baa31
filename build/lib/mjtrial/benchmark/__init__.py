"""The benchmark: tasks x methods x training seeds, tuned on development states."""
