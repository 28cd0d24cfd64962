"""At most N FOCAS sessions to one controller, handed to one caller at a time.

A Fanuc takes a handful of sessions (the 0i-F five by default; other clients, a PC's FOCAS screens,
use some), so the gateway opens them as poll groups and writes need them, up to `size`, and waits
for a free one beyond that. When the controller refuses a new session, the pool says so once (with
how many it holds) and goes on with those it has.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
from collections.abc import AsyncIterator

from gateway.errors import SourceError
from gateway.sources.focas.session import FocasSession, SessionRefused

log = logging.getLogger("gateway.clients.focas")


class SessionPool:
    def __init__(self, host: str, port: int, timeout: float, size: int) -> None:
        self.host, self.port, self.timeout = host, port, timeout
        self.size = size
        self.limit = size  # lowered when the controller refuses one more
        self.refusals = 0
        self._idle: list[FocasSession] = []
        self._all: set[FocasSession] = set()
        self._free = asyncio.Condition()

    @property
    def open_sessions(self) -> int:
        return len(self._all)

    @property
    def requests(self) -> int:
        return sum(s.requests for s in self._all)

    async def _new(self) -> FocasSession:
        session = FocasSession(self.host, self.port, self.timeout)
        await session.open()
        await session.learn()
        return session

    @contextlib.asynccontextmanager
    async def session(self) -> AsyncIterator[FocasSession]:
        """A session for one caller; one that failed is dropped, not given to the next."""
        session = await self._take()
        ok = False
        try:
            yield session
            ok = session.is_open
        finally:
            async with self._free:
                if ok:
                    self._idle.append(session)
                else:
                    self._all.discard(session)
                    session.abort()
                self._free.notify()

    async def _take(self) -> FocasSession:
        async with self._free:
            while True:
                if self._idle:
                    return self._idle.pop()
                if len(self._all) < self.limit:
                    break
                await self._free.wait()
            placeholder = FocasSession(self.host, self.port, self.timeout)
            self._all.add(placeholder)  # reserve the slot while opening
        try:
            session = await self._new()
        except SessionRefused as exc:
            async with self._free:
                self._all.discard(placeholder)
                if self._all:
                    self.refusals += 1
                    self.limit = max(1, len(self._all))
                    n = len(self._all)
                    log.warning("focas://%s:%d: the controller refused session %d (%s); using %d",
                                self.host, self.port, n + 1, exc.reason, n)  # fmt: skip
                self._free.notify()
            if not self._all:
                raise
            return await self._take()
        except BaseException:
            async with self._free:
                self._all.discard(placeholder)
                self._free.notify()
            raise
        async with self._free:
            self._all.discard(placeholder)
            self._all.add(session)
        return session

    async def close(self) -> None:
        sessions, self._all, self._idle = list(self._all), set(), []
        self.limit = self.size
        await asyncio.gather(*(s.close() for s in sessions), return_exceptions=True)


__all__ = ["SessionPool", "SessionRefused", "SourceError"]
