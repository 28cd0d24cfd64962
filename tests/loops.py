"""The event loops a test may run on: asyncio's own always, uvloop too where it is installed.

A conftest that implements pytest-asyncio's `pytest_asyncio_loop_factories` hook
with `both(item)` runs the async tests it names on each (ids `[asyncio]`,
`[uvloop]`), so that the pure asyncio path and the uvloop one (gateway/shims/loop.py)
are both tested where it is cheap: the hub, and the MQTT sink, whose paho client
hooks its socket into the loop with add_reader/add_writer.
"""

from __future__ import annotations

import asyncio
from collections.abc import Collection

import pytest

from gateway.shims.loop import LoopFactory, uvloop_factory

ASYNCIO_ONLY: dict[str, LoopFactory] = {"asyncio": asyncio.new_event_loop}


def both(item: pytest.Item, modules: Collection[str] | None = None) -> dict[str, LoopFactory]:
    """asyncio and (when installed) uvloop for tests in `modules` (file names; None: all), else asyncio."""
    if modules is not None and item.path.name not in modules:
        return ASYNCIO_ONLY
    uv = uvloop_factory()
    return ASYNCIO_ONLY if uv is None else {**ASYNCIO_ONLY, "uvloop": uv}
