"""A program's validation before it is queued: the pure pipeline, its compiled reader, its run time."""
