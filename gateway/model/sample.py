"""A variable's latest value, with the controller's timestamp and a quality."""

from __future__ import annotations

from dataclasses import dataclass
from datetime import UTC, datetime
from enum import Enum
from typing import Any, NamedTuple


class Quality(str, Enum):
    GOOD = "good"
    UNCERTAIN = "uncertain"
    BAD = "bad"


def quality_of(status: str) -> Quality:
    """OPC UA status names start with their severity: Good…, Uncertain…, Bad…."""
    if status.startswith("Good"):
        return Quality.GOOD
    if status.startswith("Uncertain"):
        return Quality.UNCERTAIN
    return Quality.BAD


def utcnow() -> datetime:
    return datetime.now(UTC)


class Sample(NamedTuple):
    """One observation of a variable.

    `status` is an OPC UA StatusCode name ("Good", "BadNotConnected", ...), so that
    the OPC UA sink can report the real code and the other sinks a readable reason.
    `value` is in engineering units (scaling already applied); when the quality is
    bad it holds the last good value, which MQTT may still show beside the quality.

    Immutable, as every sink shares it. A NamedTuple rather than a frozen dataclass:
    one is made for every change, and a frozen dataclass's `__init__` sets each field
    through `object.__setattr__`, four times slower (issue 13's profile).
    """

    value: Any
    source_ts: datetime
    status: str = "Good"
    reason: str = ""

    @property
    def quality(self) -> Quality:
        return quality_of(self.status)

    @property
    def good(self) -> bool:
        return self.status.startswith("Good")


@dataclass(frozen=True, slots=True)
class ReadBack:
    """A variable's value as its source read it back from the controller right after a write.

    `raw` is the controller's value (before scaling), `source_ts` its timestamp.
    For `hold` seconds the tree takes a notification older than this reading for
    one that was already on its way when the write was made, and drops it.
    """

    raw: Any
    source_ts: datetime
    status: str = "Good"
    reason: str = ""
    hold: float = 2.0
