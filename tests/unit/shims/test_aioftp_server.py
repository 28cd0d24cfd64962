"""The address comparison behind PeerCheckedServer (gateway/shims/aioftp_server.py)."""

from __future__ import annotations

import pytest

from gateway.shims.aioftp_server import same_host


@pytest.mark.parametrize(
    ("a", "b", "same"),
    [
        ("127.0.0.1", "127.0.0.1", True),
        ("127.0.0.1", "127.0.0.2", False),
        ("::ffff:10.0.0.5", "10.0.0.5", True),  # a dual-stack socket's view of an IPv4 client
        ("::ffff:10.0.0.5", "10.0.0.6", False),
        ("fe80::1%eth0", "fe80::1", True),
        ("2001:db8::1", "2001:db8:0:0:0:0:0:1", True),
        ("2001:db8::1", "2001:db8::2", False),
        ("", "127.0.0.1", False),
    ],
)
def test_same_host(a: str, b: str, same: bool) -> None:
    assert same_host(a, b) is same
