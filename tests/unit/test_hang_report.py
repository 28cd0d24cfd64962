"""tests/hang_report.py finds the running loop and prints its tasks, also when the loop has been frozen out of
the collector's sight (as a gateway's start-up does: gateway/shims/heap.py)."""

from __future__ import annotations

import asyncio
import gc
import threading

import pytest

from tests.hang_report import _report
from tests.waiting import wait_until


async def test_a_frozen_loops_tasks_are_reported(capsys: pytest.CaptureFixture[str]) -> None:
    async def stuck() -> None:
        await asyncio.Event().wait()

    task = asyncio.create_task(stuck(), name="test:stuck-in-teardown")
    gc.freeze()  # tests/conftest.py's gc_state_kept undoes it after the test
    try:
        threading.Thread(target=_report, name="test:reporter").start()  # as the timer's thread does
        await wait_until(lambda: "test:stuck-in-teardown" in capsys.readouterr().err or None, timeout=5,
                         message="the report to name the stuck task")  # fmt: skip
    finally:
        task.cancel()
        await asyncio.gather(task, return_exceptions=True)
