"""The audit trail: entries logged at once, stored in batches from a writer thread, queried back."""

from __future__ import annotations

import logging
import threading
from datetime import UTC, datetime, timedelta
from pathlib import Path

import pytest

from gateway.audit.store import AuditStore
from gateway.audit.trail import AuditTrail
from gateway.model.audit import MAX_TEXT, AuditEntry, as_text
from tests.waiting import wait_until

T0 = datetime(2026, 5, 6, 7, 8, 9, 123456, tzinfo=UTC)


def entry(
    i: int, *, user: str | None = "olga", machine: str = "m1", status: str = "Good", at: datetime = T0
) -> AuditEntry:
    return AuditEntry(
        at + timedelta(seconds=i),
        "write",
        machine,
        "Feed/Override",
        "opcua",
        user,
        "operator",
        "100",
        str(i),
        status,
        "" if status == "Good" else "no",
        0.002,
    )


async def test_a_burst_is_stored_in_few_transactions_and_logged_one_line_each(
    tmp_path: Path, caplog: pytest.LogCaptureFixture, monkeypatch: pytest.MonkeyPatch
) -> None:
    caplog.set_level(logging.INFO, logger="gateway.audit")
    release = stall_the_disk(monkeypatch)
    async with AuditTrail(tmp_path / "audit.sqlite3") as trail:
        trail.record(entry(0))
        await wait_until(trail._queue.empty, message="the writer to take the first entry")
        for i in range(1, 2000):  # a burst while the writer is busy
            trail.record(entry(i))
        release.set()
        await trail.flush()
        assert trail.stored == 2000
        assert trail.batches == 1 + 4  # the first entry, then 500 a transaction, not one each
    assert caplog.text.count("write m1/Feed/Override 100 -> ") == 2000
    rows = AuditStore(tmp_path / "audit.sqlite3").query(limit=5000)
    assert len(rows) == 2000 and rows[0].entry == entry(1999)  # newest first, read back whole


def stall_the_disk(monkeypatch: pytest.MonkeyPatch) -> threading.Event:
    """The writer's first insert waits until the returned event is set."""
    release = threading.Event()
    insert = AuditStore.insert

    def slow_insert(self: AuditStore, entries: list[AuditEntry]) -> int:
        release.wait(10)
        return insert(self, entries)

    monkeypatch.setattr(AuditStore, "insert", slow_insert)
    return release


async def test_entries_beyond_the_backlog_are_counted_not_blocking(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    release = stall_the_disk(monkeypatch)
    trail = AuditTrail(tmp_path / "audit.sqlite3", max_pending=10)
    async with trail:
        trail.record(entry(0))
        await wait_until(trail._queue.empty, message="the writer to take the first entry")
        for i in range(1, 100):
            trail.record(entry(i))  # returns at once, on the event loop
        assert (trail._queue.qsize(), trail.dropped) == (10, 89)
        release.set()
        await trail.flush()
    assert trail.stored == 11


async def test_queries_by_machine_user_and_time(tmp_path: Path) -> None:
    async with AuditTrail(tmp_path / "audit.sqlite3") as trail:
        trail.record(entry(0, user="olga", machine="m1"))
        trail.record(entry(10, user="ivan", machine="m2", status="BadUserAccessDenied"))
        trail.record(entry(20, user=None, machine="m1"))
    store = AuditStore(tmp_path / "audit.sqlite3")
    assert [r.entry.user for r in store.query(machine="m1")] == [None, "olga"]
    assert [r.entry.status for r in store.query(user="ivan")] == ["BadUserAccessDenied"]
    assert [r.entry.machine for r in store.query(since=T0 + timedelta(seconds=5))] == ["m1", "m2"]


async def test_old_entries_are_pruned_at_start(tmp_path: Path) -> None:
    path = tmp_path / "audit.sqlite3"
    store = AuditStore(path)
    now = datetime.now(UTC)
    store.insert([entry(0, at=now - timedelta(days=400)), entry(0, at=now - timedelta(days=1))])
    store.close()
    async with AuditTrail(path, retention_days=365):
        pass
    assert len(AuditStore(path).query()) == 1


def test_values_are_short_json() -> None:
    assert as_text(50) == "50" and as_text("part.nc") == '"part.nc"' and as_text([1.5, True]) == "[1.5,true]"
    assert as_text(float("nan")) == '"nan"' and as_text(b"\x00" * 10) == '"<10 bytes>"'
    long = as_text("G1 X1\n" * 10_000)
    assert len(long) < MAX_TEXT + 30 and long.endswith("(70002 chars)")  # JSON escapes each newline
