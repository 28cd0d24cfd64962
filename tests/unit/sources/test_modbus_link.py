"""The Modbus adapter delivers a cancellation that the library swallowed (asyncio.wait_for on Python 3.11
returns an answer that arrives together with the cancel and drops the cancel: a driver cancelled while
polling flat out polled on, and the gateway could not stop; found by the PLC bench)."""

from __future__ import annotations

import asyncio
from typing import Any

import pytest

from gateway.sources.modbus.link import ModbusLink


class _Answer:
    function_code = 3

    def isError(self) -> bool:
        return False


async def _swallowing(answered: asyncio.Event) -> Any:
    """What wait_for does in the race: the cancel arrives, the answer is there, the answer is returned."""
    try:
        await asyncio.sleep(3600)
    except asyncio.CancelledError:
        answered.set()
        return _Answer()


async def test_a_cancel_the_library_swallowed_is_delivered() -> None:
    link = ModbusLink("127.0.0.1", 502, 1, 1.0)
    answered = asyncio.Event()
    task = asyncio.create_task(link._call("FC3 holding:0-1", _swallowing(answered)))
    await asyncio.sleep(0)
    task.cancel()
    with pytest.raises(asyncio.CancelledError):
        await task
    assert answered.is_set()  # the library did answer; the cancel still won
