"""A receiver that stops reading costs the gateway a bounded queue and nothing else: OPC UA, MQTT flow on."""

from __future__ import annotations

from tests.integration.copydata.conftest import (
    Mosquitto,
    Recorder,
    RigFactory,
    TcpListener,
    mqtt_config,
    subscriber,
    targets,
)
from tests.opcua_client import Client
from tests.waiting import free_port, wait_until

X_TOPIC = "cnc/laser-sim/axes/x/position"
QUEUE_LIMIT = 16
SEND_BUFFER = 4096


async def test_a_stuck_receiver_does_not_stall_the_other_mirrors(
    make_rig: RigFactory, mosquitto: Mosquitto, recorders: list[Recorder]
) -> None:
    port = free_port()
    rig = await make_rig(
        targets({
            "name": "nesting", "transport": "tcp-client", "host": "127.0.0.1", "port": port,
            "mode": "single", "max_rate": None, "snapshot_interval": 0.01,
            "queue_limit": QUEUE_LIMIT, "send_buffer": SEND_BUFFER,
        }),
        mqtt=mqtt_config(mosquitto.port),
        loop_program="demo.nc",
    )  # fmt: skip
    emitter = rig.emitter()
    stuck = await TcpListener(emitter, port, read=False, receive_buffer=SEND_BUFFER).start()
    mqtt = subscriber(recorders, mosquitto.port, topics=[X_TOPIC])
    client = Client(f"opc.tcp://127.0.0.1:{rig.opcua_port}/cnc-gateway", timeout=5)
    await client.connect()
    try:
        x_node = client.get_node("ns=2;s=laser-sim/Axes/X/Position")
        await wait_until(lambda: stuck.connections, timeout=10, message="the gateway to connect")
        await wait_until(
            lambda: emitter.dropped > 0, timeout=30, message="the stuck receiver's queue to overflow"
        )

        # The receiver is still stuck; the rest of the gateway does not notice.
        mqtt_before = len(mqtt.on(X_TOPIC))
        opcua_before = await x_node.read_value()
        await wait_until(
            lambda: len(mqtt.on(X_TOPIC)) >= mqtt_before + 5,
            timeout=15,
            message="MQTT values to keep flowing",
        )

        async def opcua_moved() -> bool:
            return await x_node.read_value() != opcua_before

        await wait_until(opcua_moved, timeout=15, message="OPC UA values to keep flowing")

        # What the gateway holds for it stays bounded: its queue, and asyncio's buffer above the socket.
        stats = emitter.stats()
        assert stats["receivers"] == 1 and stats["queued"] <= QUEUE_LIMIT
        assert emitter.channels[0].needs_snapshot or emitter.channels[0].queued <= QUEUE_LIMIT
        assert emitter.transport.buffered <= SEND_BUFFER + QUEUE_LIMIT * 1024  # type: ignore[union-attr]
        assert stats["pending"] <= len(emitter.encoder.table)
        # and stays so: what the stuck receiver misses is superseded by the snapshot it is owed, not queued
        superseded = emitter.stats()["superseded"]
        await wait_until(
            lambda: emitter.stats()["superseded"] > superseded + 10, message="more changes passing it by"
        )
        assert emitter.stats()["queued"] <= QUEUE_LIMIT and emitter.channels[0].needs_snapshot
    finally:
        await client.disconnect()
        await stuck.stop()
