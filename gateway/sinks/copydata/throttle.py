"""Log lines that a peer can trigger at will (malformed streams, replies) are throttled.

A fuzzer hammering the tcp-server port, or a nesting package answering every
frame, must not fill the gateway's log: per key, a few lines per window are
written, and the rest are counted and summed up in one line when the next
window opens.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable


class LogThrottle:
    __slots__ = ("_clock", "_count", "_start", "_suppressed", "burst", "logger", "window")

    def __init__(
        self,
        logger: logging.Logger,
        *,
        burst: int = 10,
        window: float = 10.0,
        clock: Callable[[], float] = time.monotonic,
    ) -> None:
        self.logger = logger
        self.burst = burst
        self.window = window
        self._clock = clock
        self._start: dict[str, float] = {}
        self._count: dict[str, int] = {}
        self._suppressed: dict[str, int] = {}

    def log(self, key: str, level: int, message: str, *args: object) -> bool:
        """Log `message` unless `key` has had `burst` lines in this window; True if it was written."""
        now = self._clock()
        start = self._start.get(key)
        if start is None or now - start >= self.window:
            suppressed = self._suppressed.pop(key, 0)
            if suppressed:
                self.logger.log(
                    level,
                    "%s: %d more like this were not logged in the last %.0f s",
                    key,
                    suppressed,
                    now - (start or now),
                )
            self._start[key] = now
            self._count[key] = 0
        if self._count[key] >= self.burst:
            self._suppressed[key] = self._suppressed.get(key, 0) + 1
            return False
        self._count[key] += 1
        self.logger.log(level, message, *args)
        return True
