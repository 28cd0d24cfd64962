"""A settled heap for processes that build a large asyncua address space (the gateway, the simulator).

Start-up runs with no cyclic GC passes; then one pass, and everything start-up built is frozen out of
the collector's sight. `HeapHold` lets the gateway choose when "then" is (once its machines have
answered, off the start-up's critical path); `settled_heap()` wraps a block for the simulator.
"""

from __future__ import annotations

import contextlib
import gc
from collections.abc import Iterator

YOUNG_THRESHOLD = 50_000  # allocations between young-generation passes (Python's default: 700)


class HeapHold:
    """The collector held off from construction until `settle()` (or `release()` after a failed start).

    An OPC UA server holds over a million tracked objects (its standard namespace and our
    address space), so one full collection takes about a fifth of a second on these machines: a
    stall of every sink at a random moment, enough to trip clients' watchdogs, and many such passes
    while the address space is built. One pass when start-up is over instead; then frozen objects
    are never scanned again. The young generation's threshold is raised too: the mirror's samples
    live until the next change (seconds), so with Python's default of 700 they were promoted and
    then swept by frequent full passes over the rest (about 50 ms each, several a second at 5,000
    changes/s). What the running process allocates is still collected, in fewer, larger young passes.
    """

    def __init__(self, enable: bool | None = None) -> None:
        """`enable`: the collector on or off once settled or released (None: as it is now)."""
        self._enabled = gc.isenabled() if enable is None else enable
        self.done = False
        gc.disable()

    def settle(self) -> None:
        """Collect once (start-up's own cyclic garbage must not be frozen), freeze the rest, collect again."""
        if self.done:
            return
        self.done = True
        gc.collect()
        gc.freeze()
        if gc.get_threshold()[0] < YOUNG_THRESHOLD:
            gc.set_threshold(YOUNG_THRESHOLD, *gc.get_threshold()[1:])
        if self._enabled:
            gc.enable()

    def release(self) -> None:
        """A failed or abandoned start: nothing frozen, the collector as it was."""
        if self.done:
            return
        self.done = True
        if self._enabled:
            gc.enable()


@contextlib.contextmanager
def settled_heap() -> Iterator[None]:
    """Start-up without cyclic GC passes; then freeze what start-up built out of the collector's sight."""
    hold = HeapHold()
    try:
        yield
    except BaseException:
        hold.release()
        raise
    hold.settle()
