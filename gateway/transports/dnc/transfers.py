"""The DNC transfer log: every program that crossed a serial line, in either direction, kept in SQLite.

ISO 9001 and AS9100 shops must show which program went to (or came from) which
machine, when, by whom, and that it was the program they meant: the log keeps
machine, direction, program, size, SHA-256, start, end, outcome and user, one
row per transfer. `cnc-gateway dnc log --since …` reads the same file, whether
the gateway runs or not (WAL).

`TransferLog.record` blocks on a commit; callers on the event loop run it in a
thread (the jobs' queue thread, or `asyncio.to_thread`). Times are stored as
ISO-8601 UTC text with microseconds, which sorts like the times themselves.
"""

from __future__ import annotations

from dataclasses import dataclass
from datetime import UTC, datetime, timedelta
from pathlib import Path
from typing import Literal, get_args

from gateway.errors import TransferLogError
from gateway.sqlite_file import SqliteFile, iso, parse_iso

FILE_NAME = "transfers.sqlite3"
SCHEMA_VERSION = 1

Direction = Literal["send", "receive"]
Outcome = Literal["ok", "failed", "refused", "aborted"]
"""ok: complete and checked; failed: the line or the controller broke it off; refused: the gateway would
not take or send it (a punch without its closing %, a request for an unknown name); aborted: an operator
stopped it."""

DIRECTIONS: tuple[str, ...] = get_args(Direction)
OUTCOMES: tuple[str, ...] = get_args(Outcome)

SCHEMA = """
CREATE TABLE IF NOT EXISTS transfers (
    id INTEGER PRIMARY KEY,
    machine TEXT NOT NULL,
    direction TEXT NOT NULL CHECK (direction IN ('send', 'receive')),
    program TEXT NOT NULL,
    size INTEGER NOT NULL,
    sha256 TEXT NOT NULL,
    started TEXT NOT NULL,
    ended TEXT NOT NULL,
    outcome TEXT NOT NULL,
    user TEXT,
    detail TEXT NOT NULL
);
CREATE INDEX IF NOT EXISTS transfers_ended ON transfers (ended);
CREATE INDEX IF NOT EXISTS transfers_machine_ended ON transfers (machine, ended);
"""

COLUMNS = "machine, direction, program, size, sha256, started, ended, outcome, user, detail"


def transfers_path(state_dir: Path) -> Path:
    return state_dir / "dnc" / FILE_NAME


@dataclass(frozen=True, slots=True)
class TransferRecord:
    """One transfer. `size` and `sha256` are of the program's bytes as they crossed the line (sent: the
    framed program; received: what stood between the % markers, markers included); `user` is who asked
    for it (the job's submitter, the operator at the machine as `machine`, None when nobody is known);
    `detail` the reason of a failure or refusal, or what else is worth keeping (block reached, mode)."""

    machine: str
    direction: Direction
    program: str
    size: int
    sha256: str
    started: datetime
    ended: datetime
    outcome: Outcome
    user: str | None = None
    detail: str = ""

    def __post_init__(self) -> None:
        if self.direction not in DIRECTIONS:
            raise ValueError(f"direction {self.direction!r}: expected one of {', '.join(DIRECTIONS)}")
        if self.outcome not in OUTCOMES:
            raise ValueError(f"outcome {self.outcome!r}: expected one of {', '.join(OUTCOMES)}")

    @property
    def seconds(self) -> float:
        return (self.ended - self.started).total_seconds()


@dataclass(frozen=True, slots=True)
class TransferRow:
    """A record read back, with its row id."""

    id: int
    record: TransferRecord


class TransferLog(SqliteFile):
    """Blocking SQLite access, open once made; a missing file with `create=False` is a TransferLogError."""

    noun = "DNC transfer log"
    schema = SCHEMA
    schema_version = SCHEMA_VERSION
    error = TransferLogError

    def __init__(self, path: Path, *, create: bool = True) -> None:
        super().__init__(path)
        self.open(create=create)

    @classmethod
    def in_state_dir(cls, state_dir: Path, *, create: bool = True) -> TransferLog:
        return cls(transfers_path(state_dir), create=create)

    def record(self, rec: TransferRecord) -> int:
        """Store one transfer (committed when this returns); its row id."""
        row = (
            rec.machine,
            rec.direction,
            rec.program,
            rec.size,
            rec.sha256,
            iso(rec.started),
            iso(rec.ended),
            rec.outcome,
            rec.user,
            rec.detail,
        )
        with self._write() as db:
            cur = db.execute(f"INSERT INTO transfers ({COLUMNS}) VALUES (?,?,?,?,?,?,?,?,?,?)", row)
        return int(cur.lastrowid or 0)

    def query(
        self,
        *,
        since: datetime | None = None,
        machine: str | None = None,
        direction: Direction | None = None,
        limit: int = 1000,
    ) -> list[TransferRow]:
        """Transfers that ended at or after `since`, oldest first (a log reads down), at most the newest
        `limit`."""
        where: list[str] = []
        params: list[str | int] = []
        if since is not None:
            where.append("ended >= ?")
            params.append(iso(since))
        if machine is not None:
            where.append("machine = ?")
            params.append(machine)
        if direction is not None:
            where.append("direction = ?")
            params.append(direction)
        sql = f"SELECT id, {COLUMNS} FROM transfers"
        if where:
            sql += " WHERE " + " AND ".join(where)
        sql += " ORDER BY ended DESC, id DESC LIMIT ?"
        params.append(max(1, limit))
        with self._lock:
            rows = self.db.execute(sql, params).fetchall()
        out = [
            TransferRow(
                rowid,
                TransferRecord(
                    machine=mach,
                    direction=direc,
                    program=program,
                    size=size,
                    sha256=sha,
                    started=parse_iso(started),
                    ended=parse_iso(ended),
                    outcome=outcome,
                    user=user,
                    detail=detail,
                ),
            )
            for (rowid, mach, direc, program, size, sha, started, ended, outcome, user, detail) in rows
        ]
        out.reverse()
        return out

    def prune(self, days: int, now: datetime | None = None) -> int:
        """Delete transfers that ended more than `days` days ago (0: keep everything)."""
        if days <= 0:
            return 0
        cutoff = (now or datetime.now(UTC)) - timedelta(days=days)
        with self._write() as db:
            cur = db.execute("DELETE FROM transfers WHERE ended < ?", (iso(cutoff),))
        return cur.rowcount
