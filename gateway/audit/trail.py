"""The audit trail: log every entry at once, store it (SQLite or PostgreSQL) from a writer thread in batches.

`record()` is called on the event loop for every write and method call. It
logs one line (logger `gateway.audit`) and hands the entry to a bounded queue;
it never blocks and never touches the disk. The writer thread takes whatever
has accumulated and inserts it in one transaction, so a burst of writes costs
one commit, not one each. If the disk is so slow that `max_pending` entries
pile up, further entries are still logged but not stored, and counted.
"""

from __future__ import annotations

import asyncio
import concurrent.futures
import logging
import queue
import threading
from datetime import datetime
from pathlib import Path
from typing import Self

from gateway.audit.tables import AuditTable, open_table
from gateway.model.audit import AuditEntry

log = logging.getLogger("gateway.audit")

MAX_PENDING = 10_000
BATCH = 500


class _Flush:
    """A marker: the writer completes the future once everything before it is committed."""

    __slots__ = ("done",)

    def __init__(self) -> None:
        self.done: concurrent.futures.Future[None] = concurrent.futures.Future()


_STOP = object()


class AuditTrail:
    """`async with AuditTrail(where) as trail: tree.audit_sinks.append(trail.record)`; `where` is the SQLite
    file, or a PostgreSQL URL (gateway/audit/tables.py)."""

    def __init__(
        self, path: Path | str, *, retention_days: int = 365, max_pending: int = MAX_PENDING
    ) -> None:
        self.path = path
        self.retention_days = retention_days
        self.stored = 0
        self.dropped = 0
        self.batches = 0
        self._queue: queue.Queue[object] = queue.Queue(maxsize=max_pending)
        self._thread: threading.Thread | None = None
        self._ready: concurrent.futures.Future[None] = concurrent.futures.Future()
        self._drop_logged = 0
        self._reader: AuditTable | None = None  # for query_audit, opened at its first use
        self._reader_lock = threading.Lock()

    async def __aenter__(self) -> Self:
        self._thread = threading.Thread(target=self._run, name="audit-writer", daemon=True)
        self._thread.start()
        await asyncio.wrap_future(self._ready)  # the file is open (or the error is raised here)
        return self

    async def __aexit__(self, *exc_info: object) -> None:
        thread, self._thread = self._thread, None
        if thread is None:
            return
        await asyncio.to_thread(self._queue.put, _STOP)  # blocks only while the queue is full
        await asyncio.to_thread(thread.join)
        with self._reader_lock:
            reader, self._reader = self._reader, None
        if reader is not None:
            reader.close()

    def record(self, entry: AuditEntry) -> None:
        """Log the entry and queue it for the table; never blocks."""
        # A refused role is what an administrator looks for; other refusals (range, type) are routine.
        log.log(
            logging.WARNING if entry.status == "BadUserAccessDenied" else logging.INFO, "%s", entry.describe()
        )
        if self._thread is None:
            return
        try:
            self._queue.put_nowait(entry)
        except queue.Full:
            self.dropped += 1
            if self.dropped >= self._drop_logged * 2 or self._drop_logged == 0:
                self._drop_logged = self.dropped
                log.error("audit table is behind: %d entries logged but not stored", self.dropped)

    async def flush(self) -> None:
        """Wait until everything recorded so far is committed (for the CLI's tests, and shutdown)."""
        if self._thread is None:
            return
        marker = _Flush()
        await asyncio.to_thread(self._queue.put, marker)
        await asyncio.wrap_future(marker.done)

    async def query_audit(
        self,
        *,
        machine: str | None = None,
        user: str | None = None,
        origin: str | None = None,
        kind: str | None = None,
        since: datetime | None = None,
        limit: int = 100,
    ) -> list[AuditEntry]:
        """Entries newest first, from the table (the web console's AuditPort), in a thread of its own."""

        def read() -> list[AuditEntry]:
            with self._reader_lock:
                if self._reader is None:
                    self._reader = open_table(self.path, create=False)
                rows = self._reader.query(
                    machine=machine, user=user, origin=origin, kind=kind, since=since, limit=limit
                )
            return [row.entry for row in rows]

        return await asyncio.to_thread(read)

    # --- the writer thread ----------------------------------------------------------------------

    def _run(self) -> None:
        try:
            store = open_table(self.path)
            pruned = store.prune(self.retention_days)
        except Exception as exc:  # noqa: BLE001 - any failure to open the trail is reported to __aenter__
            self._ready.set_exception(exc)
            return
        if pruned:
            log.info("audit: removed %d entries older than %d days", pruned, self.retention_days)
        self._ready.set_result(None)
        try:
            stopping = False
            while not stopping:
                items = [self._queue.get()]
                while len(items) < BATCH:
                    try:
                        items.append(self._queue.get_nowait())
                    except queue.Empty:
                        break
                entries = [i for i in items if isinstance(i, AuditEntry)]
                try:
                    self.stored += store.insert(entries)
                    self.batches += 1 if entries else 0
                except Exception:  # a full disk must not end the trail; the log still has every entry
                    log.exception("audit: cannot store %d entries in %s", len(entries), self.path)
                for item in items:
                    if isinstance(item, _Flush):
                        item.done.set_result(None)
                    elif item is _STOP:
                        stopping = True
        finally:
            store.close()
