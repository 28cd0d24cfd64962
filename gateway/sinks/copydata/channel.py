"""One receiver's bounded queue of frames, and the rate limit of a target.

A target may have several receivers at once (each client of a tcp-server
target), and each drains at its own pace: a slow one must not hold back the
others, nor make the gateway hold an unbounded backlog for it. So every
receiver gets a `Channel`: a bounded queue that the emitter fills without ever
waiting, and that the transport empties. When a channel overflows, what it
holds is stale anyway: it is dropped (and counted), and the receiver gets a
fresh snapshot instead, built from the tree when it is about to be sent. A new
channel starts the same way, so every (re)connection begins with a snapshot.
"""

from __future__ import annotations

import asyncio
import time
from collections import deque
from collections.abc import Callable, Sequence

OutFrame = tuple[int, bytes]
"""A frame ready to send: (dwData, lpData)."""

BURST_SECONDS = 0.1  # the rate limiter lets this much of a second's frames out at once
_EPSILON = 1e-9  # clock arithmetic: 100.02 - 100.0 is a hair under 0.02


class Channel:
    """A receiver's frames on their way out; `offer` never blocks, `next_frames` waits for work."""

    __slots__ = (
        "_event",
        "_need_snapshot",
        "_queue",
        "_snapshot",
        "dropped",
        "limit",
        "peer",
        "sent",
        "snapshots",
        "superseded",
    )  # fmt: skip

    def __init__(self, peer: str, limit: int, snapshot: Callable[[], list[OutFrame]]) -> None:
        self.peer = peer
        self.limit = limit
        self.sent = 0  # frames handed to the transport
        self.dropped = 0  # frames discarded because the receiver fell behind
        self.superseded = 0  # frames not queued because a snapshot (built later, so newer) is owed anyway
        self.snapshots = 0  # snapshots sent (the first, and one after every overflow)
        self._queue: deque[OutFrame] = deque()
        self._snapshot = snapshot
        self._need_snapshot = True
        self._event = asyncio.Event()
        self._event.set()

    def __repr__(self) -> str:
        return f"<Channel {self.peer} queued={len(self._queue)} sent={self.sent} dropped={self.dropped}>"

    @property
    def queued(self) -> int:
        return len(self._queue)

    @property
    def needs_snapshot(self) -> bool:
        return self._need_snapshot

    def offer(self, frames: Sequence[OutFrame]) -> None:
        """Queue frames for this receiver; on overflow, drop the backlog and owe it a snapshot."""
        if self._need_snapshot:
            self.superseded += len(frames)  # the snapshot, built when it goes out, holds these values
            return
        queue = self._queue
        if len(queue) + len(frames) > self.limit:
            self.dropped += len(queue) + len(frames)
            queue.clear()
            self._need_snapshot = True
        else:
            queue.extend(frames)
        self._event.set()

    def request_snapshot(self) -> None:
        """Frames were lost on the way (a send timed out): start again from the current state."""
        self.dropped += len(self._queue)
        self._queue.clear()
        self._need_snapshot = True
        self._event.set()

    def take(self) -> list[OutFrame]:
        """Everything to send now, without waiting: a fresh snapshot if one is owed, else the queue."""
        self._event.clear()
        if self._need_snapshot:
            self._need_snapshot = False
            self._queue.clear()
            self.snapshots += 1
            return self._snapshot()
        frames = list(self._queue)
        self._queue.clear()
        return frames

    async def next_frames(self) -> list[OutFrame]:
        """Wait until there is something to send, then take it."""
        while True:
            await self._event.wait()
            frames = self.take()
            if frames:
                return frames


class RateLimiter:
    """A token bucket: `rate` frames per second on average, bursts of a tenth of a second's worth."""

    __slots__ = ("_clock", "_stamp", "_tokens", "capacity", "rate")

    def __init__(self, rate: float | None, clock: Callable[[], float] = time.monotonic) -> None:
        self.rate = rate
        self.capacity = max(1.0, rate * BURST_SECONDS) if rate else float("inf")
        self._clock = clock
        self._stamp = clock()
        self._tokens = self.capacity

    def _refill(self) -> None:
        if self.rate is None:
            return
        now = self._clock()
        self._tokens = min(self.capacity, self._tokens + (now - self._stamp) * self.rate)
        self._stamp = now

    def available(self) -> int:
        """Whole frames that may go out now (a very large number without a limit)."""
        if self.rate is None:
            return 1 << 30
        self._refill()
        return max(0, int(self._tokens + _EPSILON))

    def delay(self) -> float:
        """Seconds until at least one frame may go out."""
        if self.rate is None:
            return 0.0
        self._refill()
        return 0.0 if self._tokens + _EPSILON >= 1.0 else (1.0 - self._tokens) / self.rate

    def spend(self, frames: int) -> None:
        """Count frames sent; a split snapshot may overdraw, which lengthens the next wait."""
        if self.rate is not None:
            self._refill()
            self._tokens -= frames
