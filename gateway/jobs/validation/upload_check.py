"""Validation while an upload streams in: a ProgramCheck fed in the job workers' check thread.

The event loop only hands blocks over, batched to BATCH bytes; the compiled reader
releases the GIL while it reads, so the loop goes on serving OPC UA and MQTT while
a 50 MB program is checked, and the verdict is ready moments after the last byte.
If the check falls behind by more than MAX_BEHIND bytes, the upload waits for it
(backpressure) instead of buffering without bound.

Anything that goes wrong here only costs the head start: the job service then
validates the stored file as it would have without one.
"""

from __future__ import annotations

import asyncio
from collections import deque
from collections.abc import Callable
from concurrent.futures import Future
from typing import Any

from gateway.config.validation import ValidationRules
from gateway.jobs.validation.pipeline import ProgramCheck, Verdict

BATCH = 4 << 20
MAX_BEHIND = 16 << 20

#: Runs a call in the check thread (JobThreads.checking): calls run one at a time, in order.
Submit = Callable[..., "Future[Any]"]


class UploadCheck:
    """One upload's ProgramCheck, fed from the event loop and run in order in the check thread."""

    def __init__(self, rules: ValidationRules, submit: Submit) -> None:
        self._check = ProgramCheck(rules)
        self._submit = submit
        self._batch: list[bytes] = []
        self._batched = 0
        self._running: deque[tuple[Future[Any], int]] = deque()
        self._behind = 0
        self._failed: BaseException | None = None  # the check is given up; `verdict` raises this

    @property
    def changed(self) -> bool:
        """Whether the program to deliver differs from the upload (XON/XOFF stripped); after `verdict`."""
        return self._check.changed

    async def feed(self, block: bytes) -> None:
        """Take the upload's next block. Never raises: a failed check only ends the head start."""
        if self._failed is not None:
            return
        self._batch.append(block)
        self._batched += len(block)
        if self._batched >= BATCH:
            try:
                await self._hand_over()
            except Exception as exc:  # noqa: BLE001 - a bug, or the workers are shut down: the upload goes on
                self._failed = exc
                self._batch, self._running = [], deque()

    async def verdict(self, filename: str) -> Verdict:
        """The verdict for all that was fed, as `filename` (`program` empty). Raises what the check raised."""
        if self._failed is not None:
            raise self._failed
        await self._hand_over()
        while self._running:  # every block read, or the exception of the one that failed
            future, _ = self._running.popleft()
            await asyncio.wrap_future(future)
        return await asyncio.wrap_future(self._submit(self._check.finish, filename))

    async def _hand_over(self) -> None:
        if self._batched:
            data = self._batch[0] if len(self._batch) == 1 else b"".join(self._batch)
            self._batch, self._batched = [], 0
            self._running.append((self._submit(self._check.feed, data), len(data)))
            self._behind += len(data)
        while self._running and (self._running[0][0].done() or self._behind > MAX_BEHIND):
            future, size = self._running.popleft()
            self._behind -= size
            await asyncio.wrap_future(future)
