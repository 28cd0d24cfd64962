"""Alarm occurrences and their transitions: plain, frozen data shared by the store, the manager and the sinks.

An *occurrence* is one life of an alarm: raised when its id appears in the
controller's active list, cleared when it leaves it. The same id raised again
after clearing is a new occurrence with a new number. An occurrence is
*retained* (OPC UA's Retain; listed on MQTT `alarms/active`) while it still needs
attention: active, or not yet acknowledged, or, where the mapping asks for
confirmation, not yet confirmed.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from datetime import UTC, datetime
from enum import Enum
from typing import Any


class Kind(str, Enum):
    """What happened to an occurrence."""

    RAISED = "raised"
    CLEARED = "cleared"
    ACKNOWLEDGED = "acknowledged"
    CONFIRMED = "confirmed"
    QUALITY = "quality"  # the controller link changed: the alarm list is (un)certain; not stored


class Quality(str, Enum):
    GOOD = "good"
    UNCERTAIN = "uncertain"  # the controller is unreachable: the alarms are kept as they were last seen


@dataclass(frozen=True, slots=True)
class ActiveAlarm:
    """One entry of the controller's active alarm list, as read from it."""

    id: str
    text: str
    severity_class: int | None = None
    parameters: Mapping[str, Any] = field(default_factory=dict)


@dataclass(frozen=True, slots=True)
class AlarmRecord:
    """One occurrence, with its acknowledgement and confirmation. Times are UTC."""

    occurrence: int
    machine: str
    id: str
    text: str
    severity: int  # OPC UA scale, 1..1000
    severity_class: int | None
    raised_at: datetime
    parameters: Mapping[str, Any] = field(default_factory=dict)
    cleared_at: datetime | None = None
    acked_at: datetime | None = None
    acked_by: str = ""
    ack_comment: str = ""
    confirmed_at: datetime | None = None
    confirmed_by: str = ""
    confirm_comment: str = ""
    quality: Quality = Quality.GOOD
    reason: str = ""  # why the quality is not good

    @property
    def active(self) -> bool:
        return self.cleared_at is None

    @property
    def acked(self) -> bool:
        return self.acked_at is not None

    @property
    def confirmed(self) -> bool:
        return self.confirmed_at is not None

    def retained(self, confirm_required: bool) -> bool:
        return self.active or not self.acked or (confirm_required and not self.confirmed)

    def as_dict(self) -> dict[str, Any]:
        """The JSON form (MQTT, `alarms list --json`); times stay datetimes for the encoder to format."""
        return {
            "occurrence": self.occurrence,
            "id": self.id,
            "text": self.text,
            "severity": self.severity,
            "class": self.severity_class,
            "active": self.active,
            "acked": self.acked,
            "confirmed": self.confirmed,
            "raised": self.raised_at,
            "cleared": self.cleared_at,
            "acked_at": self.acked_at,
            "acked_by": self.acked_by or None,
            "ack_comment": self.ack_comment or None,
            "confirmed_at": self.confirmed_at,
            "confirmed_by": self.confirmed_by or None,
            "confirm_comment": self.confirm_comment or None,
            "quality": self.quality.value,
            "parameters": dict(self.parameters),
        }


@dataclass(frozen=True, slots=True)
class AlarmChange:
    """A transition, as listeners (the OPC UA conditions, MQTT) receive it.

    `record` is the occurrence after the change; `retained` says whether it is
    still listed (False: this was its last event).
    """

    kind: Kind
    record: AlarmRecord
    ts: datetime
    retained: bool
    user: str = ""
    comment: str = ""


def utc(ts: datetime) -> datetime:
    return ts.replace(tzinfo=UTC) if ts.tzinfo is None else ts.astimezone(UTC)


def iso(ts: datetime | None) -> str | None:
    """The stored form: UTC with microseconds, so that text order is time order."""
    return None if ts is None else utc(ts).isoformat(timespec="microseconds")


def parse_iso(text: str | None) -> datetime | None:
    return None if text is None else datetime.fromisoformat(text)
