"""Is a process's memory levelling off? A robust reading of a series of RSS samples.

RSS is noisy: a sample taken while a reconnect builds a new client, or while a
batch is being encoded, sits above the steady state, and CPython returns freed
memory to the system late or never. A leak, though, raises the *floor*. So the
series is compared by floors: the lowest sample of the last quarter against the
lowest sample of the first quarter, after a warm-up during which caches, type
tables and allocator arenas fill.
"""

from __future__ import annotations

MIB = 1024 * 1024


def floor_growth(samples: list[int], *, warmup: int) -> int:
    """Bytes the floor of `samples` rose after the first `warmup` samples (0 with too few samples)."""
    steady = samples[warmup:]
    if len(steady) < 2:
        return 0
    window = max(1, len(steady) // 4)
    return min(steady[-window:]) - min(steady[:window])


def mib(values: list[int]) -> str:
    """A series in MiB for a report line: all of it when short, its shape when long."""
    if len(values) <= 12:
        return "[" + " ".join(f"{v / MIB:.1f}" for v in values) + "] MiB"
    first, last, low, high = (v / MIB for v in (values[0], values[-1], min(values), max(values)))
    return f"[{first:.1f} … {last:.1f}, min {low:.1f}, max {high:.1f}, n={len(values)}] MiB"
