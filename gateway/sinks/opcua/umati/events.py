"""A machine alarm as a umati NotificationEventType event (OPC 40501-1 §9.4): pure translation.

Reported through the MachineTool's Notification/Messages (and the Server object), beside the
AlarmCondition event alarms.py reports for the same occurrence: Identifier is the controller's alarm
number, Message its text, Severity the OPC UA severity.
"""

from __future__ import annotations

import uuid
from typing import Any

from asyncua import ua
from asyncua.common.event_objects import BaseEvent
from asyncua.common.events import Event

from gateway.alarms.records import AlarmRecord
from gateway.model.sample import utcnow


def notification_event(
    record: AlarmRecord, messages: ua.NodeId, machine: str, event_type: ua.NodeId
) -> Event:
    event = BaseEvent(sourcenode=messages, message=record.text, severity=record.severity)  # type: ignore[no-untyped-call]
    e: Any = event  # asyncua's events take their fields as attributes
    e.emitting_node = messages
    e.EventType = event_type
    e.EventId = uuid.uuid4().bytes
    e.SourceName = machine
    e.Time = record.raised_at
    e.ReceiveTime = utcnow()
    e.add_property("Identifier", record.id, ua.VariantType.String)
    return event
