"""The gateway's heap is settled (one collection, then frozen) once its machines have been tried, not during
start-up: a full pass over an address space of 10,000 variables costs about 0.2 s, which had fallen inside
the start-up's critical path (issue 28's start-up to all Good)."""

from __future__ import annotations

import asyncio
import gc
from pathlib import Path

from gateway.app import SETTLE_AT_LATEST, Gateway
from gateway.shims.heap import YOUNG_THRESHOLD
from simulator.runner import Simulator
from tests.integration.test_mirror import MACHINE, gateway_config
from tests.waiting import free_port, wait_until

# Well inside SETTLE_AT_LATEST: a settle seen within it came from the machines, not from the cap.
SOONER = SETTLE_AT_LATEST * 2 / 3


async def settles_once_tried(gw: Gateway) -> tuple[bool, str]:
    """The machine's (connected, last error) when the heap had settled."""
    frozen = gc.get_freeze_count()
    run = asyncio.create_task(gw.run(), name="test:gateway")
    try:
        assert not gc.isenabled(), "no collector passes while the gateway starts"
        await wait_until(gc.isenabled, timeout=SOONER, message="the collector back on once start-up is over")
        status = gw.tree.machines[MACHINE].status
        assert status.is_connected or status.last_error, "settled before the machine was tried"
        assert gc.get_freeze_count() > frozen, "what start-up built is frozen"
        assert gc.get_threshold()[0] == YOUNG_THRESHOLD
        return status.is_connected, status.last_error
    finally:
        run.cancel()
        await asyncio.gather(run, return_exceptions=True)


async def test_the_heap_settles_after_the_machine_has_connected(tmp_path: Path) -> None:
    sim_port, ftp_port, gw_port = free_port(), free_port(), free_port()
    config = gateway_config(tmp_path, sim_port, gw_port)
    gc.disable()  # as `cnc-gateway run` leaves it while it loads the configuration
    async with (
        Simulator(opcua_port=sim_port, ftp_port=ftp_port, speed=20.0, store=tmp_path / "store"),
        Gateway(config, collector=True) as gw,
    ):
        connected, error = await settles_once_tried(gw)
        assert connected, error


async def test_the_heap_settles_when_the_machine_cannot_be_reached(tmp_path: Path) -> None:
    config = gateway_config(tmp_path, free_port(), free_port())  # nothing listens on the simulator's port
    gc.disable()
    async with Gateway(config, collector=True) as gw:
        connected, error = await settles_once_tried(gw)
        assert not connected
        assert "Connect" in error or "connect" in error, error


async def test_a_gateway_stopped_before_it_settled_leaves_the_collector_as_asked(tmp_path: Path) -> None:
    config = gateway_config(tmp_path, free_port(), free_port())
    gc.disable()
    frozen = gc.get_freeze_count()
    async with Gateway(config, collector=True):
        assert not gc.isenabled()
    assert gc.isenabled()
    assert gc.get_freeze_count() <= frozen
