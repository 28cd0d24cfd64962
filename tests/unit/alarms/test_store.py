"""The alarm history file: transitions in one transaction, acknowledgements persisted, history queries."""

from __future__ import annotations

from collections.abc import Callable, Iterator
from datetime import UTC, datetime, timedelta
from pathlib import Path

import pytest

from gateway.alarms.records import ActiveAlarm
from gateway.alarms.store import AlarmHistory, AlarmStore, AlarmStoreError, history_at

T0 = datetime(2026, 5, 6, 7, 0, 0, tzinfo=UTC)


@pytest.fixture(params=["sqlite", "postgresql"])
def make(request: pytest.FixtureRequest, tmp_path: Path) -> Callable[[], AlarmHistory]:
    """The same history, opened afresh at each call: the SQLite file, or a fresh PostgreSQL database
    (`alarm_history:`, gateway/alarms/postgres.py) on the server the tests use (tests/postgres.py)."""
    url = request.getfixturevalue("postgres_url") if request.param == "postgresql" else None
    return lambda: history_at(url, tmp_path)


@pytest.fixture
def store(make: Callable[[], AlarmHistory]) -> Iterator[AlarmHistory]:
    s = make().open()
    yield s
    s.close()


def test_raise_clear_and_the_transitions_are_recorded(store: AlarmHistory) -> None:
    [first, second] = store.apply(
        "m",
        [
            (ActiveAlarm("1001", "Soft limit", 3, {"Axis": "X"}), 700),
            (ActiveAlarm("2001", "Program error", 2), 400),
        ],
        [],
        T0,
    )
    assert second == first + 1
    store.apply("m", [], [(first, T0 + timedelta(seconds=5), True)], T0 + timedelta(seconds=5))
    retained = {r.occurrence: r for r in store.retained("m")}
    assert retained[first].cleared_at == T0 + timedelta(seconds=5)
    assert retained[first].parameters == {"Axis": "X"} and retained[first].severity_class == 3
    assert retained[second].active
    assert [t["kind"] for t in store.transitions(first)] == ["raised", "cleared"]


def test_acknowledgement_survives_reopening_and_is_recorded_once(make: Callable[[], AlarmHistory]) -> None:
    with make().open() as store:
        [occ] = store.apply("m", [(ActiveAlarm("1001", "Soft limit", 3), 700)], [], T0)
        assert store.acknowledge(occ, T0 + timedelta(seconds=1), "olga", "seen it", True)
        assert not store.acknowledge(occ, T0 + timedelta(seconds=2), "ivan", "me too", True)
    with make().open() as store:
        [again] = store.retained("m")
        assert again.acked and again.acked_by == "olga" and again.ack_comment == "seen it"
        assert again.acked_at == T0 + timedelta(seconds=1)
        assert [t["user"] for t in store.transitions(occ)] == ["", "olga"]


def test_an_occurrence_no_longer_retained_is_not_reloaded_but_stays_in_the_history(
    store: AlarmHistory,
) -> None:
    [occ] = store.apply("m", [(ActiveAlarm("1001", "Soft limit", 3), 700)], [], T0)
    store.acknowledge(occ, T0, "olga", "", True)
    store.apply("m", [], [(occ, T0 + timedelta(seconds=3), False)], T0 + timedelta(seconds=3))
    assert store.retained("m") == []
    [past] = store.history("m")
    assert past.occurrence == occ and not past.active and past.acked


def test_history_by_machine_since_and_active(store: AlarmHistory) -> None:
    [old] = store.apply("m", [(ActiveAlarm("1", "old"), 100)], [], T0)
    store.apply("m", [], [(old, T0 + timedelta(minutes=1), True)], T0 + timedelta(minutes=1))
    [still] = store.apply("m", [(ActiveAlarm("2", "still active"), 100)], [], T0 + timedelta(minutes=2))
    [recent] = store.apply("m", [(ActiveAlarm("3", "recent"), 100)], [], T0 + timedelta(hours=2))
    store.apply("other", [(ActiveAlarm("1", "elsewhere"), 100)], [], T0 + timedelta(hours=2))
    assert [r.occurrence for r in store.history("m")] == [recent, still, old]
    since = T0 + timedelta(hours=1)
    assert [r.occurrence for r in store.history("m", since)] == [recent, still]  # still active then
    assert [r.occurrence for r in store.history("m", active_only=True)] == [recent, still]
    assert len(store.history(None)) == 4
    assert len(store.history("m", limit=1)) == 1


def test_a_file_that_is_not_sqlite_is_a_clear_error(tmp_path: Path) -> None:
    path = tmp_path / "alarms.sqlite3"
    path.write_bytes(b"this is not a database" * 100)
    with pytest.raises(AlarmStoreError, match="cannot use the alarm history"):
        AlarmStore(path).open()


def test_opening_for_reading_needs_the_file(tmp_path: Path) -> None:
    with pytest.raises(AlarmStoreError, match="no alarm history"):
        AlarmStore(tmp_path / "missing.sqlite3").open(create=False)
