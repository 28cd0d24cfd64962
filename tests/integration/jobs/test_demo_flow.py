"""The new user's flow from the README: `curl -T part.nc ftp://…/laser-sim/` against the demo's setup
(the shipped laser-sim mapping, the simulator, the whole gateway with a real MQTT broker), and the
simulator runs the program."""

from __future__ import annotations

import asyncio
import shutil
import subprocess
from argparse import Namespace
from collections.abc import AsyncIterator, Iterator
from pathlib import Path

import pytest

from gateway.app import Gateway
from gateway.cli.demo import DEMO_INBOX_PASSWORD, DEMO_INBOX_USER, demo_inbox, demo_jobs, find_mapping
from gateway.config.gateway import GatewayConfig
from gateway.config.loader import Config, load
from gateway.jobs.queue.store import JobState
from gateway.model.events import Event
from gateway.sinks.opcua.config import OpcUaServerConfig
from simulator.runner import Simulator
from tests.integration.mqtt.conftest import MOSQUITTO, Mosquitto, mqtt_config, subscriber
from tests.opcua_client import Client
from tests.waiting import free_port, wait_until

PART = b"%\nO2001 (DEMO PART)\nG21 G90\nG0 X20 Y20\nG1 X60 F6000\nG1 Y40\nG1 X20\nG1 Y20\nM30\n%\n"


@pytest.fixture
def broker(tmp_path: Path) -> Iterator[Mosquitto]:
    if not Path(MOSQUITTO).exists():
        pytest.skip("mosquitto is not installed")
    mosquitto = Mosquitto(tmp_path / "mosquitto", free_port())
    mosquitto.start()
    try:
        yield mosquitto
    finally:
        mosquitto.stop()


@pytest.fixture
async def demo(tmp_path: Path, broker: Mosquitto) -> AsyncIterator[tuple[Gateway, Simulator, Namespace]]:
    args = Namespace(
        inbox_host="127.0.0.1", inbox_port=free_port(), sim_ftp_port=free_port(), broker=broker.port
    )
    # Real time: the part runs for about a second, long enough for the gateway to see it running.
    async with Simulator(
        opcua_port=free_port(), ftp_port=args.sim_ftp_port, speed=1.0, store=tmp_path / "sim"
    ) as sim:
        base = load([find_mapping(None)], environ={"LASER_SIM_COPYDATA_PORT": "0"})
        mapping = base.machines[0]
        driver = mapping.driver.model_copy(update={"endpoint": sim.opcua_endpoint})
        mapping = demo_jobs(mapping.model_copy(update={"driver": driver}), args)
        gateway = GatewayConfig(
            opcua=OpcUaServerConfig(endpoint=f"opc.tcp://127.0.0.1:{free_port()}/cnc-gateway"),
            state_dir=str(tmp_path / "state"),
            inbox=demo_inbox(mapping, args),
            mqtt=mqtt_config(broker.port),
        )
        config = Config(gateway, (mapping,), tmp_path)
        async with Gateway(config) as gw:
            task = asyncio.create_task(gw.run(), name="test:gateway")
            try:
                yield gw, sim, args
            finally:
                task.cancel()
                await asyncio.gather(task, return_exceptions=True)


@pytest.mark.skipif(shutil.which("curl") is None, reason="curl is not installed")
async def test_curl_to_the_inbox_delivers_and_the_simulator_runs_it(demo, tmp_path: Path, recorders) -> None:
    gw, sim, args = demo
    mqtt = subscriber(recorders, args.broker, topics=["cnc/laser-sim/jobs/#"])
    machine = gw.tree.machines["laser-sim"]
    await wait_until(
        lambda: machine.status.is_connected and machine.nodes["Machine/State"].sample.good,
        timeout=20,
        message="the gateway connected to the simulator",
    )
    events = gw.tree.events.subscribe("test")
    part = tmp_path / "part.nc"
    part.write_bytes(PART)
    url = f"ftp://{DEMO_INBOX_USER}:{DEMO_INBOX_PASSWORD}@127.0.0.1:{args.inbox_port}/laser-sim/"
    proc = await asyncio.create_subprocess_exec(
        "curl",
        "-sS",
        "--max-time",
        "30",
        "-T",
        str(part),
        url,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
    )
    _, err = await proc.communicate()
    assert proc.returncode == 0, err.decode()

    queue = gw.jobs.queue
    job = await wait_until(
        lambda: (j := queue.get(1)).state is JobState.DELIVERED and j,
        timeout=20,
        message="DELIVERED in the queue",
    )
    assert (sim.store / "DATA" / "Programs" / "part.nc").read_bytes() == PART

    # OPC UA shows it under the machine's Jobs object
    async with Client(gw.sink("opcua").endpoint) as client:
        node = client.get_node("ns=2;s=laser-sim/Jobs/LastDelivered")
        await wait_until(node.read_value, timeout=10, message="Jobs/LastDelivered")
        assert await node.read_value() == "J000001 part.nc"

    # the event stream has it (MQTT publishes these as jobs/events and jobs/J000001)
    seen: list[Event] = []

    def delivered() -> bool:
        seen.extend(events.take())
        return any(e.channel == "jobs/events" and e.payload["state"] == "DELIVERED" for e in seen)

    await wait_until(delivered, message="a DELIVERED event")
    assert all(e.machine == "laser-sim" for e in seen)

    # and MQTT: the retained job record, the event stream, and the Jobs variables
    await wait_until(
        lambda: (mqtt.last_json("cnc/laser-sim/jobs/J000001") or {}).get("state") == "DELIVERED",
        timeout=10,
        message="the job's MQTT record DELIVERED",
    )
    late = subscriber(
        recorders, args.broker, topics=["cnc/laser-sim/jobs/J000001"]
    )  # a dashboard opened later
    record = await wait_until(
        lambda: late.last("cnc/laser-sim/jobs/J000001"), message="the retained job record"
    )
    assert record.retain and record.json()["filename"] == "part.nc" and record.json()["state"] == "DELIVERED"
    states = [m.json()["state"] for m in mqtt.on("cnc/laser-sim/jobs/events")]
    assert states[:5] == ["RECEIVED", "VALIDATED", "QUEUED", "SENDING", "DELIVERED"]
    await wait_until(
        lambda: (mqtt.last_json("cnc/laser-sim/jobs/lastdelivered") or {}).get("value") == "J000001 part.nc",
        timeout=10,
        message="jobs/lastdelivered on MQTT",
    )

    # auto-start: selected, started, and run to its end by the simulator
    await wait_until(
        lambda: sim.machine.program.name == "part.nc" and sim.machine.program.part_count >= 1,
        timeout=30,
        message="the simulator to run part.nc",
    )
    job = await wait_until(
        lambda: "started part.nc" in (j := queue.get(1)).reason and j,
        timeout=20,
        message="the auto-start noted on the job",
    )
    assert job.state is JobState.DELIVERED
