"""Alarm occurrences as AlarmConditionType events: the fields clients read, and that they encode."""

from __future__ import annotations

from datetime import UTC, datetime, timedelta

from asyncua import ua
from asyncua.ua.ua_binary import variant_to_binary

from gateway.alarms.records import AlarmRecord, Quality
from gateway.sinks.opcua.conditions import SERVER, ConditionIds, condition_event, emitted_by, refresh_event

T0 = datetime(2026, 5, 6, 7, 0, 0, tzinfo=UTC)
IDS = ConditionIds(ua.NodeId("laser-sim/Alarms/17", 2), ua.NodeId("laser-sim", 2), "laser-sim")


def record(**changes: object) -> AlarmRecord:
    base = AlarmRecord(17, "laser-sim", "1001", "Soft limit X+ exceeded at line 7", 700, 3, T0)
    return AlarmRecord(**{**{k: getattr(base, k) for k in base.__dataclass_fields__}, **changes})


def fields(event: object) -> list[ua.Variant]:
    """What the server sends for a select clause naming every field (as asyncua computes it)."""
    clauses = []
    for name in event.data_types:  # type: ignore[attr-defined]
        op = ua.SimpleAttributeOperand()
        if name == "NodeId":  # the ConditionId: the NodeId attribute, no browse path
            op.AttributeId = ua.AttributeIds.NodeId
        else:
            op.AttributeId = ua.AttributeIds.Value
            op.BrowsePath = [ua.QualifiedName(part, 0) for part in name.split("/")]
        clauses.append(op)
    return event.to_event_fields(clauses)  # type: ignore[attr-defined]


def test_a_raised_alarm_is_active_unacknowledged_and_retained() -> None:
    event = condition_event(record(), IDS, event_id=b"e1", time=T0, retained=True)
    assert event.EventType == ua.NodeId(ua.ObjectIds.AlarmConditionType)
    assert event.EventId == b"e1" and event.NodeId == IDS.condition
    assert event.SourceNode == IDS.source and event.SourceName == "laser-sim"
    assert event.Message.Text == "Soft limit X+ exceeded at line 7" and event.Severity == 700
    assert event.ConditionName == "1001" and event.Retain is True
    assert getattr(event, "ActiveState/Id") is True and event.ActiveState.Text == "Active"
    assert getattr(event, "AckedState/Id") is False and getattr(event, "ConfirmedState/Id") is False
    assert getattr(event, "ActiveState/TransitionTime") == T0
    assert event.Quality == ua.StatusCode(ua.StatusCodes.Good)
    assert event.emitting_node == SERVER


def test_acknowledged_cleared_and_uncertain_states() -> None:
    done = record(
        cleared_at=T0 + timedelta(seconds=5),
        acked_at=T0 + timedelta(seconds=2),
        acked_by="olga",
        ack_comment="seen",
        quality=Quality.UNCERTAIN,
    )
    event = condition_event(
        done,
        IDS,
        event_id=b"e2",
        time=T0 + timedelta(seconds=5),
        retained=False,
        user="olga",
        last_severity=400,
    )
    assert getattr(event, "ActiveState/Id") is False and event.ActiveState.Text == "Inactive"
    assert getattr(event, "ActiveState/TransitionTime") == T0 + timedelta(seconds=5)
    assert getattr(event, "AckedState/Id") is True and getattr(
        event, "AckedState/TransitionTime"
    ) == T0 + timedelta(seconds=2)
    assert event.Comment.Text == "seen" and event.ClientUserId == "olga" and event.LastSeverity == 400
    assert event.Retain is False
    assert event.Quality == ua.StatusCode(ua.StatusCodes.UncertainLastUsableValue)


def test_every_field_encodes() -> None:
    for event in (condition_event(record(), IDS, event_id=b"e", time=T0, retained=True), refresh_event(True)):
        variants = fields(event)
        assert len(variants) == len(event.data_types) > 10
        for variant in variants:
            assert variant_to_binary(variant)


def test_a_copy_for_another_notifier_keeps_the_event_id() -> None:
    event = condition_event(record(), IDS, event_id=b"e3", time=T0, retained=True)
    twin = emitted_by(event, IDS.source)
    assert twin.emitting_node == IDS.source and event.emitting_node == SERVER
    assert twin.EventId == event.EventId == b"e3"


def test_refresh_events() -> None:
    start, end = refresh_event(True), refresh_event(False)
    assert start.EventType == ua.NodeId(ua.ObjectIds.RefreshStartEventType)
    assert end.EventType == ua.NodeId(ua.ObjectIds.RefreshEndEventType)
    assert start.EventId != end.EventId
