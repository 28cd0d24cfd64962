"""Integration tests bind free loopback ports, never the product's defaults.

To keep that true, the session holds the default ports itself (where they are
free), so a test or a spawned process that reaches for one fails at once instead
of colliding with a gateway, simulator or broker running on this machine.
"""

from __future__ import annotations

import socket
from collections.abc import Iterator
from pathlib import Path

import pytest

from tests.integration.mqtt.conftest import Mosquitto, Recorder
from tests.waiting import free_port

# Gateway OPC UA, simulator OPC UA, FTP inbox, simulator FTP, COPYDATA, MTConnect agent, simulator SHDR, web
# console. (1883 is the system broker's.) A gateway a test starts without an `http:` port of its own finds
# 8080 taken and runs without its console, retrying in the background.
DEFAULT_PORTS = (4840, 4841, 2121, 2122, 5020, 5000, 7878, 8080)


@pytest.fixture(scope="session", autouse=True)
def default_ports_are_off_limits() -> Iterator[list[int]]:
    held: list[socket.socket] = []
    for port in DEFAULT_PORTS:
        s = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
        try:
            s.bind(("0.0.0.0", port))
            s.listen(1)
        except OSError:  # something real is using it (a demo a developer left running): leave it be
            s.close()
            continue
        held.append(s)
    yield [s.getsockname()[1] for s in held]
    for s in held:
        s.close()


@pytest.fixture
def mosquitto(tmp_path: Path) -> Iterator[Mosquitto]:
    """A real Mosquitto on a free loopback port, for any integration test."""
    broker = Mosquitto(tmp_path / "mosquitto", free_port())
    broker.start()
    try:
        yield broker
    finally:
        broker.stop()


@pytest.fixture
def recorders() -> Iterator[list[Recorder]]:
    """MQTT subscribers a test starts (tests.integration.mqtt.conftest.subscriber), stopped at its end."""
    made: list[Recorder] = []
    yield made
    for rec in made:
        rec.stop()
