"""An in-process MQTT broker (amqtt) for `cnc-gateway demo` on a machine without one.

Only the demo uses this, and only when nothing answers on the configured broker
port: a real deployment points at Mosquitto, EMQX or HiveMQ. It is the one
module that imports amqtt; amqtt's errors become SinkError here.
"""

from __future__ import annotations

import asyncio
import logging
import socket
from typing import Any, Self

from gateway.errors import SinkError

log = logging.getLogger(__name__)


def broker_reachable(host: str, port: int, timeout: float = 0.5) -> bool:
    """Whether something accepts TCP connections on host:port (a broker, we assume)."""
    try:
        with socket.create_connection((host, port), timeout=timeout):
            return True
    except OSError:
        return False


class EmbeddedBroker:
    """`async with EmbeddedBroker(port=1883):` an anonymous MQTT 3.1.1 broker on 127.0.0.1."""

    def __init__(self, host: str = "127.0.0.1", port: int = 1883) -> None:
        self.host = host
        self.port = port
        self._broker: Any = None

    async def __aenter__(self) -> Self:
        try:
            from amqtt.broker import Broker
        except ImportError as exc:  # pragma: no cover - amqtt is a dependency
            raise SinkError(f"the embedded MQTT broker needs amqtt: {exc}") from None
        config = {
            "listeners": {"default": {"type": "tcp", "bind": f"{self.host}:{self.port}"}},
            "plugins": {"amqtt.plugins.authentication.AnonymousAuthPlugin": {"allow_anonymous": True}},
        }
        for name in ("amqtt", "transitions"):  # amqtt logs every connection at INFO
            logging.getLogger(name).setLevel(logging.WARNING)
        broker = Broker(config)
        try:
            await broker.start()
        except Exception as exc:  # noqa: BLE001 - amqtt raises its own BrokerError and others, untyped
            raise SinkError(
                f"cannot start the embedded MQTT broker on {self.host}:{self.port}: {exc}"
            ) from None
        self._broker = broker
        log.info("embedded MQTT broker (amqtt) listening on %s:%d", self.host, self.port)
        return self

    async def __aexit__(self, *exc_info: object) -> None:
        broker, self._broker = self._broker, None
        if broker is None:
            return
        try:
            async with asyncio.timeout(3):
                await broker.shutdown()
        except (Exception, TimeoutError) as exc:  # noqa: BLE001 - shutting down a demo broker
            log.debug("embedded broker shutdown: %s", exc)
