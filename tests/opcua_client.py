"""The OPC UA client the tests use: asyncua's, with a health probe that a loaded machine does not trip.

asyncua 2.1's client reads the server's state every `watchdog_intervall` seconds and gives the whole
connection up (state DISCONNECTED, every later request a ConnectionError) when that read takes longer than
the interval: 1 s by default. On CI's two busy cores a read can take longer than that with nothing wrong, and
a test then failed on a dead client rather than on what it checks (seen once: the README alarm walkthrough).
Tests that mean to see a lost connection still do: a closed socket is noticed at once, not by the probe.
"""

from __future__ import annotations

from typing import Any

import asyncua

PROBE_INTERVAL = 10.0  # seconds; the gateway's own OPC UA source uses its configured watchdog likewise


class Client(asyncua.Client):
    def __init__(
        self, url: str, timeout: float = 4, watchdog_intervall: float = PROBE_INTERVAL, **kw: Any
    ) -> None:
        super().__init__(url, timeout=timeout, watchdog_intervall=watchdog_intervall, **kw)
