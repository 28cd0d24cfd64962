"""Simulator → gateway (OPC UA source, OPC UA and MQTT sinks) → Mosquitto, and writes back again."""

from __future__ import annotations

import asyncio
from pathlib import Path
from typing import Any

from gateway.app import Gateway
from gateway.config.loader import load_mapping
from gateway.sinks.mqtt.config import VariableMqtt
from simulator.runner import Simulator
from tests.integration.mqtt.conftest import Mosquitto, Recorder, gateway_config, mqtt_config, subscriber
from tests.waiting import free_port, wait_until

ROOT = Path(__file__).resolve().parents[3]
OVERRIDE = "cnc/laser-sim/feed/override"


def laser_mapping(endpoint: str) -> Any:
    mapping = load_mapping(
        ROOT / "mappings" / "laser-sim.yaml",
        environ={"LASER_SIM_ENDPOINT": endpoint, "LASER_SIM_COPYDATA_PORT": "0"},
    )
    variables = [
        v.model_copy(update={"mqtt": VariableMqtt(writable=True)}) if v.path == "Feed/Override" else v
        for v in mapping.variables
    ]
    driver = mapping.driver.model_copy(update={"watchdog_interval": 0.3})
    return mapping.model_copy(update={"variables": variables, "driver": driver})


async def test_write_round_trip_and_quality_bad_when_the_simulator_stops(
    mosquitto: Mosquitto, recorders: list[Recorder], tmp_path: Path
) -> None:
    rec = subscriber(recorders, mosquitto.port, topics=["cnc/laser-sim/#"])
    sim = Simulator(opcua_port=free_port(), ftp_port=free_port(), store=tmp_path / "store")
    await sim.__aenter__()
    stopped = False
    try:
        config = gateway_config(
            laser_mapping(sim.opcua_endpoint), tmp_path / "state", mqtt_config(mosquitto.port), free_port()
        )
        async with Gateway(config) as gw:
            task = asyncio.create_task(gw.run(), name="test:gateway")
            try:
                await wait_until(
                    lambda: (rec.last_json(OVERRIDE) or {}).get("value") == 100,
                    timeout=20,
                    message="the simulator's override, good",
                )
                assert rec.last_json(OVERRIDE)["quality"] == "good" and rec.last_json(OVERRIDE)["unit"] == "%"
                await wait_until(
                    lambda: (rec.last_json("cnc/laser-sim/status") or {}).get("state") == "connected"
                )

                rec.publish(OVERRIDE + "/set", b'{"value": 50}')
                await wait_until(
                    lambda: rec.last_json(OVERRIDE + "/set/result"), message="the write's answer"
                )
                assert rec.last_json(OVERRIDE + "/set/result") == {"ok": True}
                await wait_until(
                    lambda: rec.last_json(OVERRIDE)["value"] == 50, message="the new value, published"
                )
                assert sim.machine.override == 50  # the simulator followed

                rec.publish(OVERRIDE + "/set", b"151")
                await wait_until(lambda: len(rec.on(OVERRIDE + "/set/result")) >= 2)
                assert rec.last_json(OVERRIDE + "/set/result")["status"] == "BadOutOfRange"

                await sim.__aexit__(None, None, None)
                stopped = True
                await wait_until(
                    lambda: rec.last_json(OVERRIDE)["quality"] == "bad",
                    timeout=15,
                    message="quality bad after the simulator stopped",
                )
                doc = rec.last_json(OVERRIDE)
                assert doc["value"] == 50 and doc["status"].startswith("Bad") and doc["reason"]
                await wait_until(lambda: rec.last_json("cnc/laser-sim/status")["state"] != "connected")
                status = rec.last_json("cnc/laser-sim/status")
                assert status["reason"]
            finally:
                task.cancel()
                await asyncio.gather(task, return_exceptions=True)
    finally:
        if not stopped:
            await sim.__aexit__(None, None, None)
