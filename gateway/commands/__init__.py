"""Machine commands from the mapping (start, stop, select-program, ...), registered as machine Methods:
guarded, written through the tree's one write path, confirmed by a condition within a deadline."""
