"""The durable job queue (SQLite), its records, and how its state is shown in the tree."""
