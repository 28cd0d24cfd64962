"""Validation of a program before it is queued: the pure pipeline, its compiled reader, the run-time estimate."""
