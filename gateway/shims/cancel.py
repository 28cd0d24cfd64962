"""A cancellation that asyncio.wait_for swallowed, delivered after all.

On Python 3.11, `asyncio.wait_for` returns the awaited result and drops the cancellation when the two
arrive together (fixed in 3.12). pymodbus and python-snap7 wait for each answer with it, so a driver
cancelled while polling flat out polled on, and the gateway could not stop (found by the PLC bench).
The cancel is still counted on the task (`Task.cancelling()`): `deliver_cancel()` raises it. The
adapters call it after each exchange with their library.
"""

from __future__ import annotations

import asyncio


def deliver_cancel() -> None:
    """Raise CancelledError if this task was asked to cancel and the request was lost on the way."""
    task = asyncio.current_task()
    if task is not None and task.cancelling():
        raise asyncio.CancelledError
