"""Reading the controller's parallel alarm arrays, and diffing them against the active occurrences."""

from __future__ import annotations

from datetime import UTC, datetime

from gateway.alarms.records import ActiveAlarm, AlarmRecord
from gateway.alarms.sources import diff, read_parallel

T0 = datetime(2026, 5, 6, 7, 8, 9, tzinfo=UTC)


def record(occurrence: int, alarm_id: str) -> AlarmRecord:
    return AlarmRecord(occurrence, "m", alarm_id, f"text {alarm_id}", 700, 3, T0)


def test_parallel_arrays_pair_up_by_index() -> None:
    alarms = read_parallel([1001, 2001], ["Soft limit", "Program error"], [3, 2], {"Axis": ["X", "-"]})
    assert alarms == [
        ActiveAlarm("1001", "Soft limit", 3, {"Axis": "X"}),
        ActiveAlarm("2001", "Program error", 2, {"Axis": "-"}),
    ]


def test_short_companion_arrays_leave_gaps_and_empty_slots_are_skipped() -> None:
    alarms = read_parallel([0, 1001, "", 7], ["", "Soft limit"], [3])
    assert [(a.id, a.text, a.severity_class) for a in alarms] == [
        ("1001", "Soft limit", None),
        ("7", "Alarm 7", None),
    ]


def test_no_texts_or_classes_at_all() -> None:
    assert read_parallel(["E42"]) == [ActiveAlarm("E42", "Alarm E42", None, {})]


def test_diff_names_new_and_gone_ids() -> None:
    active = {"1001": record(1, "1001"), "2001": record(2, "2001")}
    raised, cleared = diff(active, [ActiveAlarm("2001", "x"), ActiveAlarm("3001", "new")])
    assert [a.id for a in raised] == ["3001"]
    assert [r.occurrence for r in cleared] == [1]


def test_diff_of_an_unchanged_list_is_empty_even_if_a_text_changed() -> None:
    active = {"1001": record(1, "1001")}
    assert diff(active, [ActiveAlarm("1001", "another text")]) == ([], [])


def test_an_id_listed_twice_is_raised_once() -> None:
    raised, cleared = diff({}, [ActiveAlarm("5", "first"), ActiveAlarm("5", "second")])
    assert [(a.id, a.text) for a in raised] == [("5", "first")] and cleared == []


def test_retained_until_cleared_and_acknowledged_and_confirmed_when_required() -> None:
    r = record(1, "1001")
    assert r.retained(False) and r.active and not r.acked
    cleared = AlarmRecord(**{**_fields(r), "cleared_at": T0})
    assert cleared.retained(False)  # not acknowledged yet
    acked = AlarmRecord(**{**_fields(cleared), "acked_at": T0, "acked_by": "olga"})
    assert not acked.retained(False)
    assert acked.retained(True)  # confirmation required
    confirmed = AlarmRecord(**{**_fields(acked), "confirmed_at": T0})
    assert not confirmed.retained(True)


def _fields(r: AlarmRecord) -> dict[str, object]:
    return {name: getattr(r, name) for name in r.__dataclass_fields__}
