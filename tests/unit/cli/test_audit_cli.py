from __future__ import annotations

from datetime import UTC, datetime, timedelta

import pytest

from gateway.cli.audit import as_json, as_line
from gateway.cli.since import parse_since
from gateway.model.audit import AuditEntry

NOW = datetime(2026, 5, 6, 12, 0, tzinfo=UTC)


def test_since_takes_an_age_or_an_iso_time() -> None:
    assert parse_since("30m", NOW) == NOW - timedelta(minutes=30)
    assert parse_since("7d", NOW) == NOW - timedelta(days=7)
    assert parse_since("2026-05-06T07:00") == datetime(2026, 5, 6, 7, 0).astimezone()  # local, as listed
    assert parse_since("2026-05-06T09:00+02:00") == datetime(2026, 5, 6, 7, 0, tzinfo=UTC)
    with pytest.raises(ValueError, match="expected an ISO time"):
        parse_since("yesterday")


def test_one_line_says_who_what_and_the_result() -> None:
    entry = AuditEntry(
        NOW,
        "write",
        "laser-sim",
        "Feed/Override",
        "opcua",
        "otto",
        "operator",
        "100",
        "42",
        "Good",
        "",
        0.012,
    )
    line = as_line(entry)
    assert "otto@opcua/operator" in line and "laser-sim/Feed/Override 100 -> 42  ok  (12 ms)" in line
    call = AuditEntry(
        NOW,
        "call",
        "laser-sim",
        "Programs.Delete",
        "opcua",
        None,
        "viewer",
        None,
        '["a.nc"]',
        "BadUserAccessDenied",
        "role 'viewer' may not …",
        0.0,
    )
    assert "anonymous@opcua/viewer" in as_line(
        call
    ) and 'Programs.Delete("a.nc")  BadUserAccessDenied' in as_line(call)
    assert '"user": null' in as_json(call) and '"time": "2026-05-06T12:00:00.000000Z"' in as_json(call)


def test_an_acknowledgement_reads_like_a_call_with_its_comment() -> None:
    ack = AuditEntry(
        NOW,
        "acknowledge",
        "laser-sim",
        "Alarms/1001#3",
        "opcua",
        "otto",
        "operator",
        None,
        '["saw it"]',
        "Good",
        "",
        0.004,
    )
    write = AuditEntry(
        NOW, "write", "laser-sim", "Feed/Override", "opcua", "otto", "operator", "1", "2", "Good", "", 0
    )
    assert 'laser-sim/Alarms/1001#3("saw it")  ok' in as_line(ack)
    assert as_line(ack).index("otto@") == as_line(write).index("otto@")  # the kind column fits "acknowledge"
