"""The whole gateway on the simulator's PLC and chiller at once (mappings/laser-sim-s7.yaml and
chiller-sim.yaml, the demo's two auxiliary machines): their values in OPC UA (a STRING, a DATE_AND_TIME as a
DateTime) and in MQTT, an override written over MQTT that the PLC applies to the machine; and
`cnc-gateway s7 read` against the same PLC."""

from __future__ import annotations

import asyncio
import sys
import uuid
from pathlib import Path

import pytest

from gateway.app import Gateway
from gateway.config.gateway import GatewayConfig
from gateway.config.loader import Config, load_mapping
from gateway.sinks.mqtt.config import MachineMqtt, MqttConfig
from simulator.runner import Simulator
from tests.integration.mqtt.conftest import Mosquitto, Recorder, subscriber
from tests.opcua_client import Client
from tests.waiting import free_port, wait_until

ROOT = Path(__file__).resolve().parents[3]


@pytest.mark.timeout(120)
async def test_the_plc_and_the_chiller_through_the_gateway(
    mosquitto: Mosquitto, recorders: list[Recorder], tmp_path: Path
) -> None:
    faces = {"s7_port": 0, "modbus_port": 0}
    store = tmp_path / "store"
    async with Simulator(opcua_port=0, ftp_port=0, speed=10.0, loop_program="demo.nc", store=store,
                         **faces) as sim:  # fmt: skip
        assert sim.s7 is not None and sim.modbus is not None
        environ = {"LASER_SIM_S7_PORT": str(sim.s7.port), "CHILLER_SIM_PORT": str(sim.modbus.port)}
        plc = load_mapping(ROOT / "mappings" / "laser-sim-s7.yaml", environ=environ)
        plc = plc.model_copy(update={"mqtt": MachineMqtt(writable=True)})
        chiller = load_mapping(ROOT / "mappings" / "chiller-sim.yaml", environ=environ)
        opcua_port = free_port()
        gateway = GatewayConfig.model_validate(
            {
                "opcua": {"endpoint": f"opc.tcp://127.0.0.1:{opcua_port}/cnc-gateway", "security": ["None"]},
                "state_dir": str(tmp_path / "state"),
                "inbox": {"enabled": False},
            }
        ).model_copy(update={"mqtt": MqttConfig(port=mosquitto.port, client_id=f"gw-{uuid.uuid4().hex[:8]}")})
        rec = subscriber(recorders, mosquitto.port, topics=["cnc/laser-plc/#", "cnc/chiller/#"])
        client = Client(f"opc.tcp://127.0.0.1:{opcua_port}/cnc-gateway", timeout=5)
        async with Gateway(Config(gateway, (plc, chiller), tmp_path)) as gw:
            run = asyncio.create_task(gw.run(), name="gateway")
            try:
                name = "cnc/laser-plc/program/name"
                await wait_until(lambda: (rec.last_json(name) or {}).get("value") == "demo.nc", timeout=15,
                                 message="the PLC's program name (a STRING) on MQTT")  # fmt: skip
                model = "cnc/chiller/model"
                await wait_until(lambda: (rec.last_json(model) or {}).get("value") == "LX-CHILL5",
                                 timeout=15, message="the chiller on MQTT beside it")  # fmt: skip
                await client.connect()
                clock = await client.get_node("ns=2;s=laser-plc/PLC/Clock").read_data_value()
                assert (
                    clock.StatusCode.is_good() and clock.Value.Value.year >= 2024
                )  # DATE_AND_TIME -> DateTime
                assert await client.get_node("ns=2;s=laser-plc/Program/Name").read_value() == "demo.nc"
                supply = await client.get_node("ns=2;s=chiller/Temperatures/Supply").read_value()
                assert 15 < supply < 30
                rec.publish("cnc/laser-plc/requests/override/set", "85")
                await wait_until(lambda: sim.machine.override == 85, message="the override at the machine")
                override = "cnc/laser-plc/feed/override"
                await wait_until(lambda: (rec.last_json(override) or {}).get("value") == 85,
                                 message="and back from the PLC")  # fmt: skip

                proc = await asyncio.create_subprocess_exec(
                    sys.executable, "-m", "gateway.cli.main", "s7", "read", "127.0.0.1",
                    "--port", str(sim.s7.port), "DB10.DBD0", "DB10.DBW30", "DB10.DBB38:STRING[32]",
                    "DB10.DBX36.0", "DB10.DBB72:DT", "DB99.DBW0",
                    cwd=ROOT, stdout=asyncio.subprocess.PIPE, stderr=asyncio.subprocess.PIPE,
                )  # fmt: skip
                out, err = await asyncio.wait_for(proc.communicate(), timeout=60)
                assert proc.returncode == 0, err.decode()
                lines = out.decode().splitlines()
                assert lines[0] == "# PDU 480 bytes"
                assert lines[1].startswith("DB10.DBD0") and "REAL " in lines[1] and "DINT " in lines[1]
                assert "INT 85" in lines[2] and "WORD 85" in lines[2]
                assert "STRING 'demo.nc'" in lines[3]
                assert "BOOL " in lines[4]
                assert "DATE_AND_TIME 20" in lines[5]
                assert lines[6].startswith("DB99.DBW0") and "-- object does not exist" in lines[6]
            finally:
                run.cancel()
                await asyncio.gather(run, return_exceptions=True)
                await client.disconnect()
