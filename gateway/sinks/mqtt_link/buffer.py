"""Store-and-forward: what could not be sent yet, kept in order and within bounds.

Two kinds of messages, two rules:

* **Every change** (QoS 1/2): kept in order, up to `limit`. Beyond it the oldest
  is dropped and counted against its machine, except that a retained message
  that is still the newest for its topic is set aside rather than dropped, so
  the broker's retained value ends up current however long the outage lasts.
* **Latest only** (retained state at QoS 0, status documents): one message per
  topic, the newest; outside the limit, since their number is bounded by the
  number of topics.

Delivery (`take`) is oldest first. Messages taken but not acknowledged by the
broker come back with `put_front` when the connection drops. No asyncio here;
the optional `Journal` mirrors the every-change backlog into SQLite (through
gateway.sqlite_file) so that a restart does not lose it.
"""

from __future__ import annotations

import contextlib
import logging
import sqlite3
from collections import deque
from pathlib import Path

from gateway.errors import SinkError
from gateway.sqlite_file import SqliteFile

log = logging.getLogger("gateway.sinks.mqtt.buffer")  # the name log filters knew before the link moved here


class Message:
    """One MQTT publication, with what store-and-forward needs to know about it."""

    __slots__ = ("latest_only", "machine", "payload", "qos", "retain", "sent", "seq", "stored", "topic")

    def __init__(
        self,
        seq: int,
        topic: str,
        payload: bytes,
        qos: int,
        retain: bool,
        machine: str | None = None,
        latest_only: bool = False,
    ) -> None:
        self.seq = seq
        self.topic = topic
        self.payload = payload
        self.qos = qos
        self.retain = retain
        self.machine = machine  # whose drop counter a drop of this message goes to
        self.latest_only = latest_only
        self.stored = False  # a row in the journal
        self.sent = False  # handed to a broker once already: sent again, it carries the DUP flag

    def __repr__(self) -> str:
        flags = f"q{self.qos}{' r' if self.retain else ''}"
        return f"<Message #{self.seq} {self.topic} {flags} {self.payload[:40]!r}>"


class Backlog:
    """Messages waiting for the broker, bounded; see the module docstring for the rules."""

    def __init__(self, limit: int, journal: Journal | None = None) -> None:
        if limit < 1:
            raise ValueError("limit must be at least 1")
        self.limit = limit
        self.journal = journal
        self.dropped: dict[str | None, int] = {}
        self.dropped_total = 0
        self._queue: deque[Message] = deque()  # every change, oldest first
        self._latest: dict[
            str, Message
        ] = {}  # newest per topic: latest-only messages and set-aside retained ones
        self._ready: deque[Message] = deque()  # latest-only messages being delivered, oldest first
        self._newest: dict[str, int] = {}  # topic → seq of the newest retained message queued for it
        self._seq = 0
        if journal is not None:
            for msg in journal.load():
                self._seq = max(self._seq, msg.seq)
                if msg.latest_only:
                    self._latest[msg.topic] = msg
                else:
                    self._queue.append(msg)
                    if msg.retain:
                        self._newest[msg.topic] = msg.seq
            self._enforce_limit()

    # --- sizes -----------------------------------------------------------------------------

    def __len__(self) -> int:
        return len(self._queue) + len(self._ready) + len(self._latest)

    def __bool__(self) -> bool:
        return bool(self._queue or self._ready or self._latest)

    @property
    def counted(self) -> int:
        """Messages that count against the limit."""
        return len(self._queue)

    def next_seq(self) -> int:
        self._seq += 1
        return self._seq

    # --- in --------------------------------------------------------------------------------

    def put(self, msg: Message) -> None:
        """Keep a message that cannot be sent now (it is the newest of all)."""
        topic = msg.topic
        if msg.latest_only:
            old = self._latest.pop(topic, None)
            if old is not None:
                self._forget(old)
            self._latest[topic] = msg
            return
        self._queue.append(msg)
        if self.journal is not None:
            self.journal.insert(msg)
        if msg.retain:
            self._newest[topic] = msg.seq
            kept = self._latest.get(topic)
            if kept is not None and not kept.latest_only:  # a set-aside older value, now superseded
                del self._latest[topic]
                self._drop(kept)
        if len(self._queue) > self.limit:
            self._evict()

    def put_front(self, msgs: list[Message]) -> None:
        """Take back messages handed to the broker but not acknowledged (all older than the rest)."""
        journal = self.journal
        for msg in sorted(msgs, key=_seq, reverse=True):
            topic = msg.topic
            if msg.latest_only:
                if topic in self._latest:  # a newer one is already waiting
                    continue
                self._ready.appendleft(msg)
                continue
            self._queue.appendleft(msg)
            if journal is not None and not msg.stored:
                journal.insert(msg)
            if msg.retain and self._newest.get(topic, 0) < msg.seq:
                self._newest[topic] = msg.seq
        self._enforce_limit()

    def _enforce_limit(self) -> None:
        while len(self._queue) > self.limit:
            self._evict()

    def _evict(self) -> None:
        msg = self._queue.popleft()
        topic = msg.topic
        if msg.retain and self._newest.get(topic) == msg.seq and topic not in self._latest:
            self._latest[topic] = msg  # the broker's retained value must still end up current
            if self.journal is not None and msg.stored:
                self.journal.set_aside(msg)
            return
        self._drop(msg)

    def _drop(self, msg: Message) -> None:
        self.dropped[msg.machine] = self.dropped.get(msg.machine, 0) + 1
        self.dropped_total += 1
        self._forget(msg)

    def _forget(self, msg: Message) -> None:
        if msg.stored and self.journal is not None:
            self.journal.delete(msg)

    # --- out -------------------------------------------------------------------------------

    def take(self, n: int) -> list[Message]:
        """Up to `n` messages, oldest first. They stay in the journal until `done`."""
        out: list[Message] = []
        queue, ready = self._queue, self._ready
        while len(out) < n:
            if not ready and self._latest:
                ready.extend(sorted(self._latest.values(), key=_seq))
                self._latest.clear()
            if ready and (not queue or ready[0].seq < queue[0].seq):
                out.append(ready.popleft())
            elif queue:
                out.append(queue.popleft())
            else:
                break
        return out

    def discard_latest(self, topic: str) -> None:
        """Forget the waiting latest-only message of a topic (a fresher one is being sent directly)."""
        old = self._latest.pop(topic, None)
        if old is not None:
            self._forget(old)

    def done(self, msg: Message) -> None:
        """The broker has the message: forget it for good."""
        if msg.stored and self.journal is not None:
            self.journal.delete(msg)

    def clear(self) -> None:
        """Forget everything queued (used when shutting down without a journal)."""
        self._queue.clear()
        self._ready.clear()
        self._latest.clear()


def _seq(msg: Message) -> int:
    return msg.seq


class BacklogFileError(SinkError):
    """The MQTT backlog file cannot be opened or used."""


class BacklogFile(SqliteFile):
    """The journal's file: WAL, synchronous=NORMAL (a power cut may cost the last batch, not the file)."""

    noun = "MQTT backlog file"
    schema = """
CREATE TABLE IF NOT EXISTS messages (seq INTEGER PRIMARY KEY, topic TEXT NOT NULL, payload BLOB NOT NULL,
    qos INTEGER NOT NULL, retain INTEGER NOT NULL, machine TEXT, latest_only INTEGER NOT NULL);
"""
    schema_version = 1  # files from before the version was kept have 0, and the same table
    synchronous = "NORMAL"
    error = BacklogFileError


class Journal:
    """A SQLite mirror of the every-change backlog, written once per batch, read back at start-up.

    Disk trouble must not stop the gateway: the first SQLite error is logged and
    the journal turns itself off (the in-memory backlog goes on).
    """

    def __init__(self, path: Path) -> None:
        self.path = path
        self.broken = False
        self._inserts: list[tuple[int, str, bytes, int, int, str | None, int]] = []
        self._set_aside: list[tuple[int]] = []
        self._deletes: list[tuple[int]] = []
        self._file: BacklogFile | None = None
        self._db: sqlite3.Connection | None = None
        try:
            self._open(path)
        except (BacklogFileError, sqlite3.DatabaseError) as exc:
            # A file we cannot read (damaged, not a database): keep it for inspection, start afresh.
            aside = path.with_name(path.name + ".damaged")
            log.error(
                "MQTT backlog file %s is unreadable (%s); moved it to %s and starting empty", path, exc, aside
            )
            try:
                path.replace(aside)
                self._open(path)
            except (OSError, sqlite3.Error, BacklogFileError) as again:
                self._fail(again)
        except (OSError, sqlite3.Error) as exc:
            self._fail(exc)

    def _open(self, path: Path) -> None:
        file = BacklogFile(path).open()
        try:
            file.db.execute("SELECT count(*) FROM messages").fetchone()  # fails here on a damaged file
        except BaseException:
            file.close()
            raise
        self._file, self._db = file, file.db

    def _fail(self, exc: BaseException) -> None:
        if not self.broken:
            log.error(
                "MQTT backlog file %s cannot be used (%s); keeping the backlog in memory only", self.path, exc
            )
        self.broken = True
        self._close_file()

    def _close_file(self) -> None:
        file, self._file, self._db = self._file, None, None
        if file is not None:
            with contextlib.suppress(sqlite3.Error):
                file.close()

    def load(self) -> list[Message]:
        if self._db is None:
            return []
        try:
            rows = self._db.execute(
                "SELECT seq, topic, payload, qos, retain, machine, latest_only FROM messages ORDER BY seq"
            ).fetchall()
        except sqlite3.Error as exc:
            self._fail(exc)
            return []
        out = []
        for seq, topic, payload, qos, retain, machine, latest_only in rows:
            msg = Message(seq, topic, bytes(payload), qos, bool(retain), machine, bool(latest_only))
            msg.stored = True
            out.append(msg)
        if out:
            log.info("MQTT backlog: %d messages kept from the previous run will be delivered", len(out))
        return out

    def insert(self, msg: Message) -> None:
        if self._db is None:
            return
        msg.stored = True
        self._inserts.append(
            (msg.seq, msg.topic, msg.payload, msg.qos, int(msg.retain), msg.machine, int(msg.latest_only))
        )

    def set_aside(self, msg: Message) -> None:
        if self._db is not None:
            self._set_aside.append((msg.seq,))

    def delete(self, msg: Message) -> None:
        if self._db is not None:
            msg.stored = False
            self._deletes.append((msg.seq,))

    @property
    def pending(self) -> int:
        return len(self._inserts) + len(self._set_aside) + len(self._deletes)

    def commit(self) -> None:
        """Write what changed since the last commit, in one transaction."""
        db = self._db
        if db is None or not (self._inserts or self._set_aside or self._deletes):
            return
        inserts, aside, deletes = self._inserts, self._set_aside, self._deletes
        self._inserts, self._set_aside, self._deletes = [], [], []
        try:
            db.execute("BEGIN")
            if inserts:
                db.executemany("INSERT OR REPLACE INTO messages VALUES (?, ?, ?, ?, ?, ?, ?)", inserts)
            if aside:
                db.executemany("UPDATE messages SET latest_only = 1 WHERE seq = ?", aside)
            if deletes:
                db.executemany("DELETE FROM messages WHERE seq = ?", deletes)
            db.execute("COMMIT")
        except sqlite3.Error as exc:
            self._fail(exc)

    def count(self) -> int:
        if self._db is None:
            return 0
        return int(self._db.execute("SELECT count(*) FROM messages").fetchone()[0])

    def close(self) -> None:
        self.commit()
        self._close_file()
