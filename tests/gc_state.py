"""Python's garbage collector left as a test found it.

`settled_heap` (gateway/shims/heap.py), which every Gateway and Simulator start runs, raises the young
generation's threshold and freezes what start-up built; their exits unfreeze, but the threshold stays
raised. Tests run many gateways in one process, so without this each test after the first would run
with whatever GC settings the one before it left. tests/conftest.py wraps every test in `gc_state_kept()`.
"""

from __future__ import annotations

import gc
from collections.abc import Iterator
from contextlib import contextmanager


@contextmanager
def gc_state_kept() -> Iterator[None]:
    """On exit: the collector on or off, its thresholds, and nothing frozen, as on entry.

    Objects frozen before entry (by a fixture of a wider scope) stay frozen: `gc.unfreeze()` cannot tell
    them apart, so the heap is unfrozen only if nothing was frozen on entry.
    """
    enabled, threshold, frozen = gc.isenabled(), gc.get_threshold(), gc.get_freeze_count()
    try:
        yield
    finally:
        if not frozen and gc.get_freeze_count():
            gc.unfreeze()
        gc.set_threshold(*threshold)
        if enabled:
            gc.enable()
        else:
            gc.disable()
