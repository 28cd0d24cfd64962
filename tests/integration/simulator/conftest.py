from __future__ import annotations

from collections.abc import AsyncIterator
from pathlib import Path

import pytest

from simulator.runner import Simulator
from tests.waiting import free_port


@pytest.fixture
async def sim(tmp_path: Path) -> AsyncIterator[Simulator]:
    """A simulator on free loopback ports, running ten times faster than real time."""
    async with Simulator(opcua_port=free_port(), ftp_port=free_port(), speed=10.0, store=tmp_path) as s:
        yield s
