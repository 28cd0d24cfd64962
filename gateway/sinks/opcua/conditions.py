"""Alarm occurrences as OPC UA AlarmConditionType events: pure translation, no server.

One event per transition, with the fields SCADA alarm lists read: EventId (fresh
per event), ConditionId (the condition node, in the event's `NodeId`),
ConditionName (the controller's alarm number), SourceNode/SourceName (the
machine), Message (the controller's text), Severity (1..1000), Retain, Quality,
and the two-state variables ActiveState, AckedState and ConfirmedState with
their Id and TransitionTime. `emitted_by` makes the copy for each notifier the
event is reported through (the Server object and the machine's object).
"""

from __future__ import annotations

import copy
import time as _time
import uuid
from dataclasses import dataclass
from datetime import datetime
from typing import Any

from asyncua import ua
from asyncua.common.event_objects import AlarmCondition, RefreshEndEvent, RefreshStartEvent
from asyncua.common.events import Event

from gateway.alarms.records import AlarmRecord, Quality
from gateway.model.sample import utcnow
from gateway.shims.ua import new_node_id, new_status_code

SERVER = new_node_id(ua.ObjectIds.Server)
ALARM_CONDITION_TYPE = new_node_id(ua.ObjectIds.AlarmConditionType)
PROCESS_CLASS = new_node_id(ua.ObjectIds.ProcessConditionClassType)
ACKNOWLEDGE = new_node_id(ua.ObjectIds.AcknowledgeableConditionType_Acknowledge)
CONFIRM = new_node_id(ua.ObjectIds.AcknowledgeableConditionType_Confirm)
CONDITION_REFRESH = new_node_id(ua.ObjectIds.ConditionType_ConditionRefresh)
CONDITION_REFRESH2 = new_node_id(ua.ObjectIds.ConditionType_ConditionRefresh2)
HAS_NOTIFIER = new_node_id(ua.ObjectIds.HasNotifier)

QUALITY_CODES: dict[Quality, int] = {
    Quality.GOOD: ua.StatusCodes.Good,
    Quality.UNCERTAIN: ua.StatusCodes.UncertainLastUsableValue,
}

# asyncua's generated event classes declare some fields with a DataType NodeId (UtcTime, Duration)
# where a Variant needs a VariantType; these are the built-in types those DataTypes derive from.
_BASE_TYPES: dict[int, ua.VariantType] = {
    ua.ObjectIds.UtcTime: ua.VariantType.DateTime,
    ua.ObjectIds.Duration: ua.VariantType.Double,
}


@dataclass(frozen=True, slots=True)
class ConditionIds:
    """Where an occurrence lives in the address space."""

    condition: ua.NodeId  # ConditionId: the condition's own node
    source: ua.NodeId  # SourceNode: the machine's object
    source_name: str  # SourceName: the machine's name


def new_event_id() -> bytes:
    """EventIds are opaque ByteStrings, unique per event."""
    return uuid.uuid4().bytes


def _typed(event: Event) -> Event:
    for name, dtype in list(event.data_types.items()):
        if isinstance(dtype, ua.NodeId):
            event.data_types[name] = _BASE_TYPES.get(dtype.Identifier, ua.VariantType.Variant)
    return event


def _two_state(event: Event, name: str, value: bool, true: str, false: str, when: datetime | None) -> None:
    setattr(event, name, ua.LocalizedText(true if value else false))
    setattr(event, f"{name}/Id", value)
    setattr(event, f"{name}/TrueState", ua.LocalizedText(true))
    setattr(event, f"{name}/FalseState", ua.LocalizedText(false))
    if when is not None:
        setattr(event, f"{name}/TransitionTime", when)


def condition_event(
    record: AlarmRecord,
    ids: ConditionIds,
    *,
    event_id: bytes,
    time: datetime,
    retained: bool,
    last_severity: int | None = None,
    comment: str = "",
    user: str = "",
) -> Event:
    """The event that reports `record`'s state at `time` (emitted by the Server object; see `emitted_by`)."""
    event = _typed(AlarmCondition(  # type: ignore[no-untyped-call]
        sourcenode=ids.source, message=record.text, severity=record.severity
    ))  # fmt: skip
    e: Any = event  # asyncua's events take their fields as attributes no type checker knows
    e.emitting_node = SERVER
    e.add_property("NodeId", ids.condition, ua.VariantType.NodeId)  # ConditionId (not in the type)
    e.EventId = event_id
    e.SourceName = ids.source_name
    e.Time = time
    e.ReceiveTime = utcnow()
    offset = _time.localtime(time.timestamp())
    e.LocalTime = ua.TimeZoneDataType(
        Offset=offset.tm_gmtoff // 60, DaylightSavingInOffset=offset.tm_isdst > 0
    )
    e.ConditionClassId = PROCESS_CLASS
    e.ConditionClassName = ua.LocalizedText("Process")
    e.ConditionName = record.id
    e.BranchId = ua.NodeId()
    e.Retain = retained
    e.SupportsFilteredRetain = False
    _two_state(event, "EnabledState", True, "Enabled", "Disabled", None)
    e.Quality = new_status_code(QUALITY_CODES[record.quality])
    setattr(e, "Quality/SourceTimestamp", time)
    e.LastSeverity = record.severity if last_severity is None else last_severity
    e.Comment = ua.LocalizedText(comment or record.confirm_comment or record.ack_comment)
    e.ClientUserId = user
    _two_state(
        event, "ActiveState", record.active, "Active", "Inactive", record.cleared_at or record.raised_at
    )
    setattr(
        e, "ActiveState/EffectiveDisplayName", ua.LocalizedText("Active" if record.active else "Inactive")
    )
    _two_state(
        event,
        "AckedState",
        record.acked,
        "Acknowledged",
        "Unacknowledged",
        record.acked_at or record.raised_at,
    )
    _two_state(
        event,
        "ConfirmedState",
        record.confirmed,
        "Confirmed",
        "Unconfirmed",
        record.confirmed_at or record.raised_at,
    )
    e.SuppressedOrShelved = False
    e.InputNode = ua.NodeId()
    return event


def refresh_event(start: bool, *, time: datetime | None = None) -> Event:
    """RefreshStartEvent / RefreshEndEvent, around the conditions ConditionRefresh sends again."""
    event = _typed((RefreshStartEvent if start else RefreshEndEvent)(sourcenode=SERVER, severity=1))
    e: Any = event
    e.emitting_node = SERVER
    e.EventId = new_event_id()
    e.SourceName = "Server"
    e.Time = time or utcnow()
    e.ReceiveTime = utcnow()
    e.Message = ua.LocalizedText("ConditionRefresh " + ("start" if start else "end"))
    return event


def emitted_by(event: Event, notifier: ua.NodeId) -> Event:
    """The same event (same fields, same EventId) reported through another notifier."""
    twin = copy.copy(event)
    twin.emitting_node = notifier
    return twin
