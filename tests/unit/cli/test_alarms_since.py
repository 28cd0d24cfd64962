"""`cnc-gateway alarms list --since`: what a person types, read as a point in time."""

from __future__ import annotations

from datetime import UTC, datetime, timedelta

import pytest

from gateway.cli.since import parse_since

NOW = datetime(2026, 5, 6, 12, 0, 0, tzinfo=UTC)


@pytest.mark.parametrize(
    ("text", "expected"),
    [
        ("90s", NOW - timedelta(seconds=90)),
        ("15m", NOW - timedelta(minutes=15)),
        ("2h", NOW - timedelta(hours=2)),
        ("1.5d", NOW - timedelta(hours=36)),
        ("2026-05-06T10:00:00Z", datetime(2026, 5, 6, 10, tzinfo=UTC)),
        ("2026-05-06T10:00:00+02:00", datetime(2026, 5, 6, 8, tzinfo=UTC)),
    ],
)
def test_durations_and_times(text: str, expected: datetime) -> None:
    assert parse_since(text, NOW) == expected


def test_dates_without_a_zone_are_local_time() -> None:
    got = parse_since("2026-05-06", NOW)
    assert got.tzinfo is not None and got.replace(tzinfo=None) == datetime(2026, 5, 6)


def test_today_is_local_midnight() -> None:
    got = parse_since("today", NOW)
    assert (got.hour, got.minute) == (0, 0) and got <= NOW


@pytest.mark.parametrize("text", ["yesterday", "5 parsecs", "", "-2h"])
def test_anything_else_says_what_is_accepted(text: str) -> None:
    with pytest.raises(ValueError, match="expected a duration"):
        parse_since(text, NOW)
