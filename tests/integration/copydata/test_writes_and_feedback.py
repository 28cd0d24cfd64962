"""Frames from the nesting software: feedback on the event bus, MQTT and OPC UA; with accept_writes,
writes that reach the simulator, and refusals that reach nothing."""

from __future__ import annotations

import json
import logging
import struct

import pytest

from tests.integration.copydata.conftest import (
    Mosquitto,
    Recorder,
    RigFactory,
    TcpReceiver,
    mqtt_config,
    single,
    subscriber,
    targets,
)
from tests.opcua_client import Client
from tests.waiting import wait_until

FEEDBACK_TOPIC = "cnc/laser-sim/copydata/feedback"


async def test_writes_refusals_and_feedback_everywhere(
    make_rig: RigFactory, mosquitto: Mosquitto, recorders: list[Recorder], caplog: pytest.LogCaptureFixture
) -> None:
    caplog.set_level(logging.INFO, logger="gateway.sinks.copydata")
    rig = await make_rig(
        targets(
            {
                "name": "nesting",
                "transport": "tcp-server",
                "bind": "127.0.0.1",
                "port": 0,
                "accept_writes": True,
            }
        ),
        mqtt=mqtt_config(mosquitto.port),
    )
    await rig.connected()
    # The replies act with access.copydata_role (never an implied one), and start-up says what they may write.
    assert any(
        r.getMessage().startswith("copydata laser-sim/nesting: replies act as operator and may write ")
        for r in caplog.records
    ), "start-up says what the COPYDATA replies may write"
    mqtt = subscriber(recorders, mosquitto.port, topics=[FEEDBACK_TOPIC])
    events = rig.machine.tree.events.subscribe("test")
    client = TcpReceiver(rig.emitter())
    await client.connect(await rig.server_port())
    opcua = Client(f"opc.tcp://127.0.0.1:{rig.opcua_port}/cnc-gateway", timeout=5)
    await opcua.connect()
    try:
        # Feed/Override (id 6, UInt16) = 50: a write like any other, and it reaches the controller.
        client.send(single(6, struct.pack("<H", 50)))
        await wait_until(lambda: rig.sim.machine.override == 50, message="the simulator's override at 50")
        await wait_until(lambda: rig.value("Feed/Override") == 50, message="the mirror showing it")
        ok = await wait_until(lambda: mqtt.last_json(FEEDBACK_TOPIC), message="the feedback on MQTT")
        assert ok["items"] == [{"id": 6, "path": "Feed/Override", "value": 50, "write": {"ok": True}}]
        assert ok["target"] == "nesting" and ok["dwdata"] == 1 and "ts" in ok

        # Axes/X/Position (id 1) is read-only: refused, logged, nothing written.
        x_before = rig.sim.machine.axes[0].actual
        client.send(single(1, struct.pack("<d", 777.0)))
        refused = await wait_until(
            lambda: (d := mqtt.last_json(FEEDBACK_TOPIC)) and d["items"][0]["id"] == 1 and d,
            message="the refusal",
        )
        assert refused["items"][0]["write"] == {
            "ok": False, "error": "laser-sim/Axes/X/Position is read-only", "status": "BadNotWritable",
        }  # fmt: skip
        assert rig.sim.machine.axes[0].actual == x_before != 777.0
        assert any(
            "refused" in r.getMessage() and "Axes/X/Position" in r.getMessage() for r in caplog.records
        )

        # The same documents went through the event bus, and the latest is in OPC UA's Status.
        channels = [e.channel for e in events.take()]
        assert channels.count("copydata/feedback") == 2
        status = opcua.get_node("ns=2;s=laser-sim/Status/CopydataFeedback")

        async def status_shows_the_refusal() -> bool:
            return '"status":"BadNotWritable"' in await status.read_value()

        await wait_until(status_shows_the_refusal, message="Status/CopydataFeedback in OPC UA")
        assert json.loads(await status.read_value())["peer"].startswith("127.0.0.1:")
        targets_text = await opcua.get_node("ns=2;s=laser-sim/Status/CopydataTargets").read_value()
        assert targets_text.startswith("nesting: tcp-server 127.0.0.1:") and targets_text.endswith(
            "listening, 1 client"
        )
        assert rig.emitter().stats()["writes"] == 1 and rig.emitter().stats()["refused_writes"] == 1
    finally:
        await opcua.disconnect()
        await client.close()
