"""The agent's buffer on disk (`mtconnect.persist: true`): a restart keeps the instanceId and the sequence.

One SQLite file, `<state_dir>/mtconnect.sqlite3` (through gateway/sqlite_file.py): the
observations still in the ring, and a few facts in `meta`. The agent appends what is
new a few times a second, in one transaction, from a thread of its own, and deletes
what fell out of the ring. At a clean stop it writes the last of them and marks the
file clean; at the next start a clean file with the same device model gives the buffer
back, with the same instanceId and sequence numbers, so a client's `from=` still works.

A file that was not closed cleanly (the process was killed) may lack the last
observations that clients already saw; numbering on from it could give a sequence
number twice, with different data. So then, as when the device model changed, the
agent starts afresh with a new instanceId, which tells every client to start over.
`synchronous = NORMAL`: a power cut loses the last transactions, which is the same case.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

from gateway.errors import SinkError
from gateway.sqlite_file import SqliteFile

Row = tuple[
    int, str, str, str, str, str | None, str | None, str | None, str | None,
    int | None, float | None, str | None, float | None, str | None,
]  # fmt: skip

_COLUMNS = (
    "sequence, item, timestamp, value, level, native_code, native_severity, qualifier, condition_id, "
    "sample_count, sample_rate, reset_triggered, duration, asset_type"
)


def store_path(state_dir: Path) -> Path:
    return state_dir / "mtconnect.sqlite3"


class StoreError(SinkError):
    pass


@dataclass(frozen=True, slots=True)
class Kept:
    """What a clean earlier run left: its instanceId, where its numbering stood, its observations."""

    instance_id: int
    next_sequence: int
    rows: list[Row]


class ObservationStore(SqliteFile):
    noun = "MTConnect buffer"
    schema = """
        CREATE TABLE IF NOT EXISTS meta (key TEXT PRIMARY KEY, value TEXT NOT NULL);
        CREATE TABLE IF NOT EXISTS observations (
            sequence INTEGER PRIMARY KEY, item TEXT NOT NULL, timestamp TEXT NOT NULL, value TEXT NOT NULL,
            level TEXT NOT NULL, native_code TEXT, native_severity TEXT, qualifier TEXT, condition_id TEXT,
            sample_count INTEGER, sample_rate REAL, reset_triggered TEXT, duration REAL, asset_type TEXT
        );
    """
    schema_version = 1
    error = StoreError
    synchronous = "NORMAL"

    def _meta(self) -> dict[str, str]:
        return {row["key"]: row["value"] for row in self.db.execute("SELECT key, value FROM meta")}

    def kept(self, fingerprint: str, size: int) -> tuple[Kept | None, str]:
        """The earlier run's buffer if it may be reused, and why not otherwise ("" when it may)."""
        with self._lock:
            meta = self._meta()
            if not meta:
                return None, "no earlier run"
            if meta.get("clean") != "1":
                return None, "the previous run did not stop cleanly"
            if meta.get("fingerprint") != fingerprint:
                return None, "the device model changed"
            try:
                instance, nxt = int(meta["instance_id"]), int(meta["next_sequence"])
            except (KeyError, ValueError):
                return None, "the kept buffer's facts are unreadable"
            rows = self.db.execute(
                f"SELECT {_COLUMNS} FROM observations WHERE sequence >= ? ORDER BY sequence", (nxt - size,)
            ).fetchall()
            return Kept(instance, nxt, [tuple(r) for r in rows]), ""

    def begin(self, fingerprint: str, instance_id: int, *, fresh: bool) -> None:
        """This run starts: its facts, not clean until `finish`; `fresh` drops what an earlier run kept."""
        with self._write() as db:
            if fresh:
                db.execute("DELETE FROM observations")
            db.executemany(
                "INSERT OR REPLACE INTO meta (key, value) VALUES (?, ?)",
                [("fingerprint", fingerprint), ("instance_id", str(instance_id)), ("clean", "0")],
            )

    def append(self, rows: Sequence[Row], keep_from: int) -> None:
        """New observations, and forget those below `keep_from` (out of the ring)."""
        if not rows:
            return
        with self._write() as db:
            db.executemany(
                f"INSERT OR REPLACE INTO observations ({_COLUMNS}) VALUES ({', '.join('?' * 14)})", rows
            )
            db.execute("DELETE FROM observations WHERE sequence < ?", (keep_from,))

    def finish(self, next_sequence: int) -> None:
        """A clean stop: everything is written; the next run may go on from `next_sequence`."""
        with self._write() as db:
            db.executemany(
                "INSERT OR REPLACE INTO meta (key, value) VALUES (?, ?)",
                [("next_sequence", str(next_sequence)), ("clean", "1")],
            )

    def facts(self) -> dict[str, str]:
        with self._lock:
            return self._meta()
