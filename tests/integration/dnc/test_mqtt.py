"""A drip-feed on MQTT: the job's retained record with its progress, and DripPause/DripResume as MQTT
commands, through a whole gateway (app.Gateway) and a real Mosquitto."""

from __future__ import annotations

import asyncio
import json
from pathlib import Path
from typing import Any

from gateway.app import Gateway
from gateway.config.gateway import GatewayConfig
from gateway.config.jobs import InboxConfig
from gateway.config.loader import Config, load_mapping
from gateway.sinks.opcua.config import OpcUaServerConfig
from tests.integration.dnc.rig import Mode, drip_program, face, simulator
from tests.integration.dnc.test_jobs import serial_mapping
from tests.integration.mqtt.conftest import Mosquitto, Recorder, mqtt_config, subscriber
from tests.waiting import free_port, wait_until


async def test_drip_progress_and_pause_over_mqtt(
    tmp_path: Path, mosquitto: Mosquitto, recorders: list[Recorder]
) -> None:
    rec = subscriber(recorders, mosquitto.port, topics=["cnc/lathe/jobs/#", "cnc/lathe/commands/+/result"])
    async with simulator(tmp_path, mode=Mode.DRIP) as sim:
        path = tmp_path / "lathe.yaml"
        path.write_text(
            serial_mapping(face(sim).socket_url or "", opcua=sim.opcua_port) + "mqtt: {commands: true}\n"
        )
        config = Config(
            GatewayConfig(
                opcua=OpcUaServerConfig(endpoint=f"opc.tcp://127.0.0.1:{free_port()}/cnc-gateway"),
                state_dir=str(tmp_path / "state"),
                inbox=InboxConfig(enabled=False),
                mqtt=mqtt_config(mosquitto.port),
                http=None,
            ),
            (load_mapping(path, environ={}),),
            tmp_path,
        )
        async with Gateway(config) as gw:
            task = asyncio.create_task(gw.run(), name="test:gateway")
            try:
                await wait_until(lambda: gw.sink("mqtt").online, message="the gateway on the broker")  # type: ignore[attr-defined]
                assert gw.jobs is not None
                reply = await gw.jobs.submit_bytes(
                    "lathe", "part.nc", drip_program(400), user="al", origin="t"
                )
                topic = f"cnc/lathe/jobs/{reply.job_id}"

                def records() -> list[dict[str, Any]]:
                    return [json.loads(m.payload) for m in rec.on(topic) if m.payload]

                await wait_until(
                    lambda: any(r.get("block") for r in records()),
                    timeout=30,
                    message="a record with a block",
                )
                sending = [r for r in records() if r.get("block")][-1]
                assert (
                    sending["state"] == "SENDING" and sending["lead"] is not None and sending["remaining"] > 0
                )
                rec.publish("cnc/lathe/commands/DripPause", b"{}")
                await wait_until(
                    lambda: rec.on("cnc/lathe/commands/DripPause/result"), message="the pause answered"
                )
                assert json.loads(rec.on("cnc/lathe/commands/DripPause/result")[0].payload)["ok"] is True
                await wait_until(
                    lambda: any(r.get("held") == "paused" for r in records()), message="a paused record"
                )
                rec.publish("cnc/lathe/commands/DripResume", b"{}")
                await wait_until(
                    lambda: any(r["state"] == "DELIVERED" for r in records()), timeout=60, message="DELIVERED"
                )
            finally:
                task.cancel()
                await asyncio.gather(task, return_exceptions=True)
