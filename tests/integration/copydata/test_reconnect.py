"""A tcp-client target reconnects when the nesting software's listener comes back, snapshot first."""

from __future__ import annotations

from tests.integration.copydata.conftest import RigFactory, TcpListener, targets
from tests.waiting import free_port, wait_until


async def test_the_gateway_reconnects_and_starts_again_with_a_snapshot(make_rig: RigFactory) -> None:
    port = free_port()
    rig = await make_rig(targets({
        "name": "nesting", "transport": "tcp-client", "host": "127.0.0.1", "port": port, "mode": "single",
        "max_rate": 100, "backoff": {"initial": 0.05, "max": 0.2},
    }))  # fmt: skip
    emitter = rig.emitter()
    await wait_until(lambda: "connecting (" in emitter.describe(), message="the gateway trying to connect")
    listener = await TcpListener(emitter, port).start()
    try:
        await rig.start_program()
        await wait_until(lambda: listener.connections and len(listener.connections[0].frames) > 10,
                         message="frames on the first connection")  # fmt: skip
        first = listener.connections[0]
        assert first.frames[0][0] == 2 and all(
            dw == 1 for dw, _ in first.frames[1:]
        )  # snapshot, then singles
        await listener.stop()  # the nesting software goes away
        await wait_until(lambda: "connecting (" in emitter.describe(), message="the gateway noticing")
        assert emitter.stats()["receivers"] == 0
        listener = await TcpListener(emitter, port).start()  # and comes back on the same port
        await wait_until(lambda: len(listener.connections) == 1 and listener.connections[0].frames,
                         message="the reconnection's first frame")  # fmt: skip
        dwdata, snapshot = listener.connections[0].frames[0]
        assert dwdata == 2
        assert set(snapshot) == {
            v.name for v in emitter.encoder.table
        }  # every variable, not just what changed
        assert emitter.transport.connects == 2  # type: ignore[union-attr]
        assert emitter.describe().endswith("connected")
    finally:
        await listener.stop()
