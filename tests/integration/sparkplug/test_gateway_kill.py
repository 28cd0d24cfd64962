"""The gateway as a process, killed with SIGKILL: the broker publishes its will, an NDEATH whose bdSeq is the
one the NBIRTH of that session carried; started again, the next NBIRTH has the next bdSeq (kept in the state
directory, so that a late will of the killed process never matches the new session); a clean stop
(SIGTERM) publishes the NDEATH itself."""

from __future__ import annotations

import asyncio
from pathlib import Path

import pytest

from tests.integration.drills import processes
from tests.integration.mqtt.conftest import Mosquitto
from tests.integration.sparkplug.conftest import start_host
from tests.integration.sparkplug.host import Seen, SparkplugHost
from tests.waiting import free_port, wait_until

KILLS = 2


def bdseq(seen: Seen) -> int:
    metric = seen.metric("bdSeq")
    assert metric is not None
    return int(metric.value)


@pytest.mark.timeout(120)
async def test_bdseq_matches_between_nbirth_and_ndeath_across_kills(
    mosquitto: Mosquitto, hosts: list[SparkplugHost], tmp_path: Path
) -> None:
    host = start_host(hosts, mosquitto.port)
    mapping = processes.write_yaml(
        tmp_path / "laser-sim.yaml", processes.laser_sim(free_port())
    )  # no controller
    processes.write_yaml(
        tmp_path / "gateway.yaml",
        {
            "opcua": {"endpoint": f"opc.tcp://127.0.0.1:{free_port()}/cnc-gateway", "security": ["None"]},
            "state_dir": "state",
            "machines": [mapping.name],
            "sparkplug": {
                "group_id": "cnc",
                "broker": {
                    "port": mosquitto.port,
                    "client_id": "kill-test",
                    "keepalive": 5,
                    "reconnect": {"initial": 0.1, "max": 0.5},
                },
            },
        },
    )
    gateway = processes.gateway(tmp_path, tmp_path / "gateway.yaml")
    try:
        for round_ in range(KILLS + 1):
            gateway.start()
            await wait_until(
                lambda r=round_: len(host.of("NBIRTH")) > r,
                timeout=30,  # type: ignore[misc]
                message=f"NBIRTH {round_ + 1}\n{gateway.tail()}",
            )
            await wait_until(
                lambda r=round_: len(host.of("DDEATH", "laser-sim")) > r,
                timeout=30,  # type: ignore[misc]
                message="the device born and dead (no controller)",
            )
            if round_ < KILLS:
                await asyncio.to_thread(gateway.kill)  # the broker publishes the will
            else:
                assert await asyncio.to_thread(gateway.stop) == 0  # SIGTERM: a clean stop, its own NDEATH
            await wait_until(
                lambda r=round_: len(host.of("NDEATH")) > r,
                timeout=30,  # type: ignore[misc]
                message=f"NDEATH {round_ + 1}",
            )
    finally:
        gateway.stop()
    births, deaths = host.of("NBIRTH"), host.of("NDEATH")
    assert [bdseq(b) for b in births] == [bdseq(d) for d in deaths]  # each death names its own session
    first = bdseq(births[0])
    assert [bdseq(b) for b in births] == [(first + i) % 256 for i in range(KILLS + 1)]
    assert "Traceback" not in gateway.tail(100_000)
