"""STATE of a primary host: Sparkplug 3.0 JSON, 2.2's ONLINE/OFFLINE, and the timestamp rules."""

from __future__ import annotations

import json

import pytest
from hypothesis import given
from hypothesis import strategies as st

from gateway.codecs.sparkplug import BadState, HostState, PrimaryHost, parse_state


@given(online=st.booleans(), timestamp=st.integers(0, 2**64 - 1))
def test_sparkplug_3_json(online: bool, timestamp: int) -> None:
    payload = json.dumps({"online": online, "timestamp": timestamp}).encode()
    assert parse_state(payload) == HostState(online, timestamp)


def test_other_keys_are_ignored_and_integral_floats_accepted() -> None:
    assert parse_state(b'{"timestamp": 1.7e12, "online": true, "version": "4.0"}') == HostState(
        True, 1_700_000_000_000
    )


@pytest.mark.parametrize(("text", "online"), [(b"ONLINE", True), (b"OFFLINE", False), (b" ONLINE\n", True)])
def test_sparkplug_2_2_text(text: bytes, online: bool) -> None:
    assert parse_state(text) == HostState(online, None, legacy=True)


@pytest.mark.parametrize(
    ("payload", "fragment"),
    [
        (b"", "expected"),
        (b"online", "expected"),
        (b"Online", "expected"),
        (b"\xff\xfe", "not UTF-8 text (byte 0)"),
        (b'{"online": true', "malformed JSON"),
        (b'{"online": true, "timestamp": 1}{}', "malformed JSON: Extra data"),
        (b'{"timestamp": 1}', '"online" must be true or false, got nothing'),
        (b'{"online": "true", "timestamp": 1}', '"online" must be true or false, got "true"'),
        (b'{"online": 1, "timestamp": 1}', '"online" must be true or false, got 1'),
        (b'{"online": true}', '"timestamp" must be ms since 1970 (an unsigned integer), got nothing'),
        (b'{"online": true, "timestamp": -1}', "got -1"),
        (b'{"online": true, "timestamp": 1.5}', "got 1.5"),
        (b'{"online": true, "timestamp": "1700000000000"}', 'got "1700000000000"'),
        (b'{"online": true, "timestamp": true}', "got true"),
        (b'{"online": true, "timestamp": NaN}', "got NaN"),
        (b'{"online": true, "timestamp": 18446744073709551616}', "got 18446744073709551616"),
        (b'{"online": ' + b"[" * 60_000, "malformed JSON"),  # nested too deeply for the parser
        (b" " * 70_000, "more than a STATE payload needs"),
    ],
)
def test_payloads_that_are_no_state_are_refused(payload: bytes, fragment: str) -> None:
    with pytest.raises(BadState) as info:
        parse_state(payload)
    assert fragment in str(info.value)


def test_a_primary_host_online_then_offline() -> None:
    host = PrimaryHost()
    assert host.online is False
    assert host.feed(HostState(True, 100)) is True and host.online
    assert host.feed(HostState(True, 100)) is False  # the retained copy again
    assert host.feed(HostState(False, 100)) is True and not host.online


def test_an_offline_older_than_the_last_online_is_a_replaced_sessions_will() -> None:
    host = PrimaryHost()
    host.feed(HostState(True, 200))
    assert host.feed(HostState(False, 150)) is False and host.online


def test_an_online_older_than_the_last_online_is_stale() -> None:
    host = PrimaryHost()
    host.feed(HostState(True, 200))
    host.feed(HostState(False, 250))
    assert host.feed(HostState(True, 199)) is False and not host.online
    assert host.feed(HostState(True, 300)) is True and host.online


def test_a_first_state_counts_whatever_its_timestamp() -> None:
    host = PrimaryHost()
    assert host.feed(HostState(False, 5)) is False and not host.online
    assert host.feed(HostState(True, 1)) is True and host.online


def test_legacy_states_always_count_and_reset_forgets() -> None:
    host = PrimaryHost()
    host.feed(HostState(True, 500))
    assert host.feed(HostState(False, None, legacy=True)) is True and not host.online
    assert host.feed(HostState(True, None, legacy=True)) is True and host.online
    host.reset()
    assert not host.online
    assert host.feed(HostState(True, 1)) is True  # the old timestamp no longer holds it back
