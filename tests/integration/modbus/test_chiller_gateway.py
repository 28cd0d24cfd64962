"""The whole gateway on the simulator's chiller (mappings/chiller-sim.yaml over the simulator's Modbus TCP
face): its values in OPC UA and MQTT, a setpoint written from OPC UA and from MQTT down to the chiller, the
device's own refusal answered to the OPC UA client by its name's status, and an outage of the face."""

from __future__ import annotations

import asyncio
import json
import uuid
from pathlib import Path

import pytest
from asyncua import ua

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
async def test_the_chiller_through_the_gateway(
    mosquitto: Mosquitto, recorders: list[Recorder], tmp_path: Path
) -> None:
    sim = Simulator(opcua_port=0, ftp_port=0, modbus_port=0, speed=10.0, loop_program="demo.nc",
                    store=tmp_path / "store")  # fmt: skip
    await sim.__aenter__()
    assert sim.modbus is not None
    modbus_port = sim.modbus.port
    mapping = load_mapping(
        ROOT / "mappings" / "chiller-sim.yaml", environ={"CHILLER_SIM_PORT": str(modbus_port)}
    )
    variables = [
        v.model_copy(update={"range": None}) if v.path == "Setpoint" else v for v in mapping.variables
    ]
    driver = mapping.driver.model_copy(
        update={"reconnect": mapping.driver.reconnect.model_copy(update={"max": 0.5})}
    )
    mapping = mapping.model_copy(
        update={"variables": variables, "mqtt": MachineMqtt(writable=True), "driver": driver}
    )
    opcua_port = free_port()
    gateway = GatewayConfig.model_validate(
        {
            "opcua": {"endpoint": f"opc.tcp://127.0.0.1:{opcua_port}/cnc-gateway", "security": ["None"]},
            "state_dir": str(tmp_path / "state"),
            "inbox": {"enabled": False},
            "access": {"anonymous": "operator"},
        }
    ).model_copy(update={"mqtt": MqttConfig(port=mosquitto.port, client_id=f"gw-{uuid.uuid4().hex[:8]}")})
    rec = subscriber(recorders, mosquitto.port, topics=["cnc/chiller/#"])
    client = Client(f"opc.tcp://127.0.0.1:{opcua_port}/cnc-gateway", timeout=5)
    try:
        async with Gateway(Config(gateway, (mapping,), tmp_path)) as gw:
            run = asyncio.create_task(gw.run(), name="gateway")
            try:
                await client.connect()
                supply = client.get_node("ns=2;s=chiller/Temperatures/Supply")
                model = "cnc/chiller/model"
                await wait_until(lambda: (rec.last_json(model) or {}).get("value") == "LX-CHILL5",
                                 timeout=15, message="the chiller's model name on MQTT")  # fmt: skip
                value = await supply.read_data_value()
                assert value.StatusCode.is_good() and 15 < value.Value.Value < 30
                assert (await client.get_node("ns=2;s=chiller/Model").read_value()) == "LX-CHILL5"
                assert (rec.last_json("cnc/chiller/temperatures/return") or {}).get("quality") == "good"

                setpoint = client.get_node("ns=2;s=chiller/Setpoint")
                await setpoint.write_value(ua.DataValue(ua.Variant(18.0, ua.VariantType.Float)))
                assert sim.chiller.setpoint == 18.0
                assert await setpoint.read_value() == 18.0
                with pytest.raises(ua.UaStatusCodeError) as refused:  # the chiller takes 10-30 degC only
                    await setpoint.write_value(ua.DataValue(ua.Variant(35.0, ua.VariantType.Float)))
                assert refused.value.code == ua.StatusCodes.BadOutOfRange
                assert sim.chiller.setpoint == 18.0

                rec.publish("cnc/chiller/setpoint/set", json.dumps(21.5))
                await wait_until(
                    lambda: sim.chiller.setpoint == 21.5, message="the MQTT write at the chiller"
                )
                rec.publish("cnc/chiller/pumpon/set", "false")
                await wait_until(lambda: not sim.chiller.pump_on, message="the pump switched off over MQTT")
                running = "cnc/chiller/state/pumprunning"
                await wait_until(lambda: (rec.last_json(running) or {}).get("value") is False,
                                 message="the pump stopped, as the chiller reports")  # fmt: skip

                await sim.__aexit__(None, None, None)
                await wait_until(lambda: (rec.last_json("cnc/chiller/flow") or {}).get("quality") == "bad",
                                 timeout=5, message="Bad on MQTT while the chiller is away")  # fmt: skip
                assert (await supply.read_data_value(raise_on_bad_status=False)).StatusCode.is_bad()
                sim = Simulator(opcua_port=0, ftp_port=0, modbus_port=modbus_port, store=tmp_path / "store")
                await sim.__aenter__()
                await wait_until(lambda: (rec.last_json("cnc/chiller/flow") or {}).get("quality") == "good",
                                 timeout=10, message="Good again once it is back")  # fmt: skip
            finally:
                run.cancel()
                await asyncio.gather(run, return_exceptions=True)
                await client.disconnect()
    finally:
        await sim.__aexit__(None, None, None)
