"""The sink interface: something upstream that mirrors the tree (OPC UA, MQTT, COPYDATA).

A sink is an async context manager with a long-running `run()`. It subscribes to
the tree's change hub, drains its own subscription at its own pace, and sends
writes back through `Machine.write`, which answers with a reasoned RequestError.
"""

from __future__ import annotations

from typing import Protocol, Self


class Sink(Protocol):
    name: str

    async def __aenter__(self) -> Self: ...

    async def __aexit__(self, *exc_info: object) -> None: ...

    async def run(self) -> None:
        """Mirror changes until cancelled."""
        ...
