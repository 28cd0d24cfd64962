"""A shard's watch on its supervisor (gateway/shards/parent.py); the kill itself: test_fleet_supervisor.py."""

from __future__ import annotations

import asyncio
import os

import pytest

from gateway.shards.parent import SUPERVISOR_ENV, orphan_watch, stop_when_orphaned, supervisor_of


@pytest.mark.parametrize(
    ("text", "pid"), [("4242", 4242), (" 17 ", 17), ("", None), ("abc", None), ("-3", None), ("1.5", None)]
)
def test_the_supervisor_pid_is_read_from_the_environment(text: str, pid: int | None) -> None:
    assert supervisor_of({SUPERVISOR_ENV: text}) == pid


def test_a_gateway_run_on_its_own_watches_nothing() -> None:
    assert orphan_watch({}) == []
    [(name, _)] = orphan_watch({SUPERVISOR_ENV: str(os.getppid())})
    assert name == "fleet:supervisor-watch"


async def test_a_shard_whose_supervisor_lives_keeps_running() -> None:
    watch = asyncio.create_task(stop_when_orphaned(os.getppid(), check_every=0.01))
    for _ in range(20):  # twenty looks at the parent: none may end the watch (nor signal this process)
        await asyncio.sleep(0.01)
        assert not watch.done()
    watch.cancel()
    with pytest.raises(asyncio.CancelledError):
        await watch
