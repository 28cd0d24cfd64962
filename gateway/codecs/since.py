"""A point in time from what a person types: `90s`, `15m`, `2h`, `7d`, `2w`, `today`, or ISO-8601. Pure.

Used by `alarms list`/`audit list --since` (gateway/cli/since.py) and the web console's audit filter.
An ISO time without a zone is local time, as the lists print it.
"""

from __future__ import annotations

import re
from datetime import UTC, datetime, timedelta

_DURATION = re.compile(r"^\s*(\d+(?:\.\d+)?)\s*([smhdw])\s*$")
_SECONDS = {"s": 1, "m": 60, "h": 3600, "d": 86400, "w": 604800}


def parse_since(text: str, now: datetime | None = None) -> datetime:
    """The point in time `text` names (aware); ValueError says which forms are accepted."""
    now = now or datetime.now(UTC)
    m = _DURATION.match(text)
    if m:
        return now - timedelta(seconds=float(m.group(1)) * _SECONDS[m.group(2)])
    stripped = text.strip()
    if stripped.lower() == "today":
        return now.astimezone().replace(hour=0, minute=0, second=0, microsecond=0)
    if stripped[-1:] in ("z", "Z"):  # UTC, however Python's fromisoformat reads the letter
        stripped = stripped[:-1] + "+00:00"
    try:
        when = datetime.fromisoformat(stripped)
    except ValueError:
        raise ValueError(
            f"{text!r}: expected an ISO time or date (2026-05-06T07:00, 2026-05-06; local time unless it "
            "names a zone: Z, +02:00), or expected a duration back from now (90s, 15m, 2h, 7d, 2w) or 'today'"
        ) from None
    return when if when.tzinfo else when.astimezone()  # naive: local time
