"""The audit trail: every write and every method call, who did it, and what came of it."""
