"""One Haas MDC connection over asyncio: a query at a time, answers matched by their label.

The control allows two connections and sends every answer to both, so an answer this client did not
ask for (another client's, or a late one) is counted (`unsolicited`) and skipped, never taken for the
one awaited. Lines that are not MDC answers are counted (`junk`) and skipped. A broken or silent
connection is a `SourceError`.
"""

from __future__ import annotations

import asyncio

from gateway.codecs.haas_mdc.protocol import Junk, LineReader, Query, Reply
from gateway.errors import SourceError

READ_SIZE = 4096


class MdcConnection:
    def __init__(self, host: str, port: int, timeout: float) -> None:
        self.host, self.port, self.timeout = host, port, timeout
        self.unsolicited = 0
        self.junk = 0
        self.queries = 0
        self._reader: asyncio.StreamReader | None = None
        self._writer: asyncio.StreamWriter | None = None
        self._lines = LineReader()
        self._pending: list[Reply] = []
        self._lock = asyncio.Lock()

    @property
    def endpoint(self) -> str:
        return f"mdc://{self.host}:{self.port}"

    @property
    def is_open(self) -> bool:
        return self._writer is not None and not self._writer.is_closing()

    async def open(self) -> None:
        try:
            async with asyncio.timeout(self.timeout):
                self._reader, self._writer = await asyncio.open_connection(self.host, self.port)
        except (OSError, TimeoutError) as exc:
            raise SourceError(_reason(exc)) from None

    def close(self) -> None:
        writer, self._writer = self._writer, None
        if writer is not None:
            writer.transport.abort()

    async def ask(self, query: Query) -> Reply:
        """Send one query and wait for its answer (the control's `?` included)."""
        async with self._lock:
            writer, reader = self._writer, self._reader
            if writer is None or reader is None or writer.is_closing():
                raise SourceError("the MDC connection is closed")
            self._pending = [r for r in self._pending if not self._stale(r)]
            writer.write(query.encode())
            self.queries += 1
            try:
                async with asyncio.timeout(self.timeout):
                    while True:
                        while self._pending:
                            reply = self._pending.pop(0)
                            if reply.answers(query):
                                return reply
                            self.unsolicited += 1
                        data = await reader.read(READ_SIZE)
                        if not data:
                            raise SourceError("the control closed the connection")
                        for event in self._lines.feed(data):
                            if isinstance(event, Junk):
                                self.junk += 1
                            else:
                                self._pending.append(event)
            except SourceError:
                self.close()
                raise
            except (OSError, TimeoutError) as exc:
                self.close()
                raise SourceError(_reason(exc)) from None

    def _stale(self, reply: Reply) -> bool:
        """Answers read before this query was sent are someone else's: counted and dropped."""
        self.unsolicited += 1
        return True


def _reason(exc: BaseException) -> str:
    if isinstance(exc, TimeoutError):
        return "timed out (no answer)"
    if isinstance(exc, ConnectionRefusedError):
        return "connection refused"
    if isinstance(exc, OSError) and exc.strerror:
        return exc.strerror
    return str(exc) or type(exc).__name__
