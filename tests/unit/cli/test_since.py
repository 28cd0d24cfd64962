"""--since of `alarms list` and `audit list`: one parser, the union of what each took before."""

from __future__ import annotations

import argparse
import time
from collections.abc import Iterator
from datetime import UTC, datetime, timedelta, timezone

import pytest
from hypothesis import given
from hypothesis import strategies as st

from gateway.cli import alarms, audit
from gateway.cli.since import parse_since, since_arg

NOW = datetime(2026, 5, 6, 12, 0, 0, tzinfo=UTC)
BERLIN = timezone(timedelta(hours=2))  # Europe/Berlin in May (CEST)


@pytest.fixture
def in_berlin(monkeypatch: pytest.MonkeyPatch) -> Iterator[None]:
    """Local time two hours ahead of UTC, so that local and UTC readings differ."""
    monkeypatch.setenv("TZ", "Europe/Berlin")
    time.tzset()
    yield
    monkeypatch.undo()
    time.tzset()


@pytest.mark.parametrize(
    ("text", "expected"),
    [
        ("90s", NOW - timedelta(seconds=90)),
        ("30m", NOW - timedelta(minutes=30)),
        ("2h", NOW - timedelta(hours=2)),
        ("1.5d", NOW - timedelta(hours=36)),
        ("2w", NOW - timedelta(weeks=2)),  # alarms took weeks, audit did not
        (" 7d ", NOW - timedelta(days=7)),
        ("2026-05-06T10:00:00Z", datetime(2026, 5, 6, 10, tzinfo=UTC)),
        ("2026-05-06T10:00:00z", datetime(2026, 5, 6, 10, tzinfo=UTC)),
        ("2026-05-06T09:00+02:00", datetime(2026, 5, 6, 7, tzinfo=UTC)),
    ],
)
def test_durations_and_zoned_times(text: str, expected: datetime) -> None:
    assert parse_since(text, NOW) == expected


def test_a_time_or_date_without_a_zone_is_local_time(in_berlin: None) -> None:
    assert parse_since("2026-05-06T07:00", NOW) == datetime(2026, 5, 6, 5, 0, tzinfo=UTC)
    assert parse_since("2026-05-06", NOW) == datetime(2026, 5, 5, 22, 0, tzinfo=UTC)
    assert parse_since("2026-05-06 07:00:30", NOW).utcoffset() == timedelta(hours=2)


def test_today_is_local_midnight(in_berlin: None) -> None:
    got = parse_since("today", NOW)  # 14:00 in Berlin
    assert got == datetime(2026, 5, 6, 0, 0, tzinfo=BERLIN)
    assert parse_since("Today", datetime(2026, 5, 6, 23, 30, tzinfo=UTC)) == datetime(
        2026, 5, 7, 0, 0, tzinfo=BERLIN
    )  # already the 7th in Berlin


@pytest.mark.parametrize("text", ["yesterday", "5 parsecs", "", "-2h", "2H", "2026-13-01", "12:00"])
def test_anything_else_says_every_accepted_form(text: str) -> None:
    with pytest.raises(ValueError) as info:
        parse_since(text, NOW)
    message = str(info.value)
    assert "expected a duration" in message and "expected an ISO time" in message and "'today'" in message


@given(amount=st.integers(min_value=0, max_value=10_000), unit=st.sampled_from("smhdw"))
def test_every_duration_is_that_long_ago(amount: int, unit: str) -> None:
    seconds = {"s": 1, "m": 60, "h": 3600, "d": 86400, "w": 604800}[unit]
    assert NOW - parse_since(f"{amount}{unit}", NOW) == timedelta(seconds=amount * seconds)


@given(st.datetimes(datetime(1970, 1, 2), datetime(9999, 12, 30), timezones=st.just(UTC)))
def test_an_iso_time_reads_back_as_itself(when: datetime) -> None:
    assert parse_since(when.isoformat(), NOW) == when
    assert parse_since(when.isoformat().replace("+00:00", "Z"), NOW) == when


@pytest.mark.parametrize("command", [alarms, audit])
def test_both_commands_take_the_same_since(command: object) -> None:
    parser = argparse.ArgumentParser()
    command.register(parser.add_subparsers())  # type: ignore[attr-defined]
    name = command.__name__.rsplit(".", 1)[-1]  # type: ignore[attr-defined]
    args = parser.parse_args([name, "list", "--since", "2w"])
    assert isinstance(args.since, datetime) and args.since < datetime.now(UTC) - timedelta(days=13)
    assert since_arg("2026-05-06T10:00:00Z") == datetime(2026, 5, 6, 10, tzinfo=UTC)
    with pytest.raises(SystemExit) as exit_:
        parser.parse_args([name, "list", "--since", "yesterday"])
    assert exit_.value.code == 2
