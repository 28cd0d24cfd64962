"""Reconnect delays: exponential, capped, with a little jitter.

Jitter matters in a shop with many machines behind one gateway: when a switch
reboots, every driver loses its controller at the same instant, and without
jitter they would all retry in lockstep. The jitter only ever shortens a delay,
so the configured maximum really is the maximum. Pure: no I/O, no asyncio.
"""

from __future__ import annotations

import random
from collections.abc import Callable, Iterator


def backoff_delays(
    initial: float,
    factor: float,
    maximum: float,
    *,
    jitter: float = 0.1,
    rand: Callable[[], float] = random.random,
) -> Iterator[float]:
    """Endless delays: initial, initial*factor, … capped at maximum, each shortened by up to `jitter`."""
    base = min(initial, maximum)
    while True:
        yield base * (1.0 - jitter * rand())
        base = min(base * factor, maximum)
