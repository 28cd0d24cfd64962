"""Noise mode end to end: changes at the set rate, with a sequence number and a source timestamp."""

from __future__ import annotations

import asyncio
import gc
import weakref
from datetime import UTC, datetime, timedelta
from pathlib import Path

import pytest
from asyncua import ua

from simulator.noise import NoiseSpec
from simulator.runner import Simulator
from tests.opcua_client import Client
from tests.waiting import free_port, wait_until


class Seen:
    def __init__(self) -> None:
        self.values: dict[str, list[tuple[float, datetime]]] = {}

    def datachange_notification(self, node: object, val: float, data: object) -> None:
        dv = data.monitored_item.Value  # type: ignore[attr-defined]
        self.values.setdefault(str(node), []).append((val, dv.SourceTimestamp))


async def test_noise_changes_arrive_in_sequence_round_robin_with_their_write_time(tmp_path: Path) -> None:
    spec = NoiseSpec(20, 0.0, per_folder=8)
    async with Simulator(opcua_port=free_port(), ftp_port=free_port(), store=tmp_path, noise=spec) as sim:
        assert sim.noise is not None
        async with Client(sim.opcua_endpoint, timeout=10) as client:
            ns = await client.get_namespace_index("urn:cnc-simulator:plc")
            nodes = [client.get_node(ua.NodeId(spec.node_id(i), ns)) for i in range(20)]
            seen = Seen()
            subscription = await client.create_subscription(20, seen)
            await subscription.subscribe_data_change(nodes, queuesize=50)
            await asyncio.sleep(0.2)
            started = datetime.now(UTC)
            sim.noise.set_rate(400.0)
            await wait_until(lambda: sim.noise.written >= 200, timeout=10, message="200 noise changes")
            sim.noise.set_rate(0.0)
            written = sim.noise.written
            await wait_until(
                lambda: sum(len(v) for v in seen.values.values()) >= written + 20, timeout=10,
                message="every change at the client",
            )  # fmt: skip
            assert sim.noise.stats().written == written
            for index, node in enumerate(nodes):
                got = [value for value, _ in seen.values[str(node)]]
                assert got[0] == 0.0  # the initial value, before the noise started
                changes = got[1:]
                assert changes == [
                    float(k) for k in range(index + 1, written + 1, 20)
                ]  # change k goes to (k-1) % 20
                stamps = [ts for _, ts in seen.values[str(node)][1:]]
                now = datetime.now(UTC)
                assert all(started - timedelta(seconds=1) <= ts.replace(tzinfo=UTC) <= now for ts in stamps)
            with pytest.raises(ua.UaStatusCodeError) as refused:  # read-only, like any controller variable
                await nodes[0].write_value(ua.DataValue(ua.Variant(5.0, ua.VariantType.Double)))
            assert refused.value.code == ua.StatusCodes.BadNotWritable


async def test_the_simulators_address_space_is_frozen_out_of_the_collectors_sight(tmp_path: Path) -> None:
    """A full collection over asyncua's million objects stalled the simulator for about 0.2 s every second
    or two when flat out: every value a client received then was that much older (issue 13)."""
    gc.unfreeze()
    async with Simulator(
        opcua_port=free_port(), ftp_port=free_port(), store=tmp_path, noise=NoiseSpec(50)
    ) as sim:
        assert gc.isenabled()
        frozen = gc.get_freeze_count()
        assert frozen > 100_000, f"only {frozen} objects frozen"  # the standard namespace and ours
        async with Client(sim.opcua_endpoint, timeout=10) as client:  # it still serves
            assert await client.get_namespace_index("urn:cnc-simulator:plc") > 0
        assert sim._opcua is not None and sim._opcua._server is not None
        server = weakref.ref(sim._opcua._server)
    # Stopped: what it built was unfrozen and collected; what lives on (a gateway beside it) is frozen again.
    assert server() is None
    assert gc.get_freeze_count() < frozen
