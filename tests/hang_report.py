"""What a test that hangs is waiting for: its event loop's tasks, with their stacks, before the timeout.

pytest-timeout (pyproject: 120 s) prints the threads' stacks when it fires; for an asyncio test those show
only the loop waiting in `select`. Some earlier CI runs ended in such a timeout in a gateway's shutdown,
and never again when run alone. So `watch()` arms a timer shortly before the timeout; if the test is still
running then, every running event loop prints its tasks and where each is suspended (to stderr, which
pytest shows with the failure). A test that ends in time costs a timer thread that is cancelled.
"""

from __future__ import annotations

import asyncio
import contextlib
import gc
import sys
import threading
from collections.abc import Iterator
from typing import Any

LEAD = 15.0  # seconds before the test's timeout


def _dump(loop: asyncio.AbstractEventLoop) -> None:
    tasks = asyncio.all_tasks(loop)
    print(f"\n=== hang report: {len(tasks)} task(s) on {loop!r}", file=sys.stderr)
    for task in tasks:
        print(f"--- {task.get_name()}: {task!r}", file=sys.stderr)
        task.print_stack(limit=12, file=sys.stderr)


def _running_loops() -> list[asyncio.AbstractEventLoop]:
    """The loops running in any thread, found on the threads' stacks (`run_forever`'s `self`).

    Not through `gc.get_objects()`, as at first: a gateway's start-up freezes what exists then
    (gateway/shims/heap.py), the loop with it, and frozen objects are not listed (CI's next hang in a
    teardown printed no report)."""
    loops: dict[int, asyncio.AbstractEventLoop] = {}
    for frame in sys._current_frames().values():
        f: Any = frame
        while f is not None:
            candidate = f.f_locals.get("self") if f.f_code.co_name == "run_forever" else None
            if isinstance(candidate, asyncio.AbstractEventLoop) and candidate.is_running():
                loops[id(candidate)] = candidate
            f = f.f_back
    for o in gc.get_objects():  # loops not frozen and not on a stack in run_forever (other loop classes)
        if isinstance(o, asyncio.AbstractEventLoop) and o.is_running():
            loops.setdefault(id(o), o)
    return list(loops.values())


def _report() -> None:
    for loop in _running_loops():
        with contextlib.suppress(RuntimeError):  # closed meanwhile
            loop.call_soon_threadsafe(_dump, loop)


@contextlib.contextmanager
def watch(timeout: float | None) -> Iterator[None]:
    """Report the running loops' tasks if the block is still running `LEAD` seconds before `timeout`."""
    if not timeout or timeout <= LEAD:
        yield
        return
    timer = threading.Timer(timeout - LEAD, _report)
    timer.daemon = True
    timer.start()
    try:
        yield
    finally:
        timer.cancel()
