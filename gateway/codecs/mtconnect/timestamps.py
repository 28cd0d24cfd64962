"""MTConnect timestamps: ISO 8601 in UTC, to the microsecond, with a `Z`.

Parsing is strict about the shape (a date, `T`, a time) and lenient where adapters
differ: the zone may be `Z`, an offset, or missing (read as UTC, as the reference
agent does), and the fraction may have any number of digits (kept to microseconds).
"""

from __future__ import annotations

import re
from datetime import UTC, datetime, timedelta

_ISO = re.compile(
    r"(\d{4})-(\d{2})-(\d{2})T(\d{2}):(\d{2}):(\d{2})(?:\.(\d{1,12}))?(Z|[+-]\d{2}:?\d{2})?\Z", re.ASCII
)


def parse_timestamp(text: str) -> datetime | None:
    """The aware UTC datetime `text` names, or None if it is not an ISO 8601 date-time."""
    m = _ISO.match(text)
    if m is None:
        return None
    year, month, day, hour, minute, second, fraction, zone = m.groups()
    micro = int((fraction or "0")[:6].ljust(6, "0"))
    try:
        value = datetime(
            int(year), int(month), int(day), int(hour), int(minute), int(second), micro, tzinfo=UTC
        )
    except ValueError:
        return None
    if zone and zone != "Z":
        sign = 1 if zone[0] == "+" else -1
        digits = zone[1:].replace(":", "")
        offset = timedelta(hours=int(digits[:2]), minutes=int(digits[2:]))
        if offset >= timedelta(hours=24):
            return None
        value -= sign * offset
    return value


def format_timestamp(value: datetime) -> str:
    """`2024-05-01T12:00:00.000000Z`; a naive datetime is taken as UTC."""
    if value.tzinfo is not None:
        value = value.astimezone(UTC).replace(tzinfo=None)
    return value.isoformat(timespec="microseconds") + "Z"
