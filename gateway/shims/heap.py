"""A settled heap for processes that build a large asyncua address space (the gateway, the simulator).

`settled_heap()` wraps start-up: no cyclic GC passes while it builds, one pass at the
end, then everything it built frozen out of the collector's sight.
"""

from __future__ import annotations

import contextlib
import gc
from collections.abc import Iterator

YOUNG_THRESHOLD = 50_000  # allocations between young-generation passes (Python's default: 700)


@contextlib.contextmanager
def settled_heap() -> Iterator[None]:
    """Start-up without cyclic GC passes; then freeze what start-up built out of the collector's sight.

    An OPC UA server holds over a million tracked objects (its standard namespace and our
    address space), so one full collection takes about half a second on these machines: a
    half-second stall of every sink at a random moment, enough to trip clients' watchdogs,
    and many such passes while the address space is built. One pass at the end instead;
    then frozen objects are never scanned again. The young generation's threshold is
    raised too: the mirror's samples live until the next change (seconds), so with
    Python's default of 700 they were promoted and then swept by frequent full passes
    over the rest (about 50 ms each, several a second at 5,000 changes/s). What the
    running gateway allocates is still collected, in fewer, larger young passes.
    """
    enabled = gc.isenabled()
    gc.disable()
    try:
        yield
    except BaseException:
        if enabled:
            gc.enable()
        raise
    gc.collect()  # once: start-up's own cyclic garbage must not be frozen with the rest
    gc.freeze()
    if gc.get_threshold()[0] < YOUNG_THRESHOLD:
        gc.set_threshold(YOUNG_THRESHOLD, *gc.get_threshold()[1:])
    if enabled:
        gc.enable()
