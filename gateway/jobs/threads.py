"""The job queue's own worker threads: one for the queue file, two for checks and file copies.

Blocking work (SQLite, reading and validating programs) runs off the event loop,
but not in asyncio's shared default executor: that pool is small (cores + 4)
and anything else in the process that blocks in it (a crowd of slow clients,
another component) would stall the queue. One thread for the queue file also
serialises its use without a lock held across awaits.
"""

from __future__ import annotations

import asyncio
import functools
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor
from typing import Any, TypeVar

T = TypeVar("T")


class JobThreads:
    def __init__(self, workers: int = 2) -> None:
        self._queue = ThreadPoolExecutor(1, thread_name_prefix="jobs-queue")
        self._work = ThreadPoolExecutor(workers, thread_name_prefix="jobs-work")

    async def queue(self, fn: Callable[..., T], *args: Any, **kwargs: Any) -> T:
        """Run a JobQueue call."""
        return await asyncio.get_running_loop().run_in_executor(self._queue, functools.partial(fn, *args, **kwargs))

    async def work(self, fn: Callable[..., T], *args: Any, **kwargs: Any) -> T:
        """Run file I/O or a validation."""
        return await asyncio.get_running_loop().run_in_executor(self._work, functools.partial(fn, *args, **kwargs))

    async def shutdown(self) -> None:
        """Wait for running calls to end (cancelled awaits do not stop a thread), then stop."""
        await asyncio.to_thread(self._work.shutdown, True, cancel_futures=True)
        await asyncio.to_thread(self._queue.shutdown, True, cancel_futures=True)
