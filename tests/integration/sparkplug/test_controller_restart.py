"""A controller that goes away and comes back: DDEATH when it drops (its values turn stale at the host, not
Bad one by one), nothing of that device until it is back, then a DBIRTH; the node's seq never skips."""

from __future__ import annotations

from pathlib import Path

from tests.integration.mqtt.conftest import Mosquitto
from tests.integration.sparkplug.conftest import MACHINE, laser_sparkplug, sparkplug_config, start_host
from tests.integration.sparkplug.host import SparkplugHost
from tests.integration.sparkplug.test_session import online_birth, seq_gaps
from tests.waiting import wait_until


async def test_ddeath_when_the_controller_drops_and_dbirth_when_it_returns(
    mosquitto: Mosquitto, hosts: list[SparkplugHost], tmp_path: Path
) -> None:
    host = start_host(hosts, mosquitto.port)
    async with laser_sparkplug(tmp_path, sparkplug_config(mosquitto.port), loop_program="demo.nc") as laser:
        await wait_until(lambda: online_birth(host), message="the DBIRTH of the machine online")
        mark = host.count()
        await wait_until(
            lambda: any(s.kind == "DDATA" for s in host.since(mark)), message="the program's data"
        )

        await laser.stop_sim()
        await wait_until(lambda: any(s.kind == "DDEATH" for s in host.since(mark)), message="the DDEATH")
        assert not laser.machine.status.is_connected
        births = len(host.of("DBIRTH", MACHINE))
        await laser.start_sim()
        await wait_until(
            lambda: len(host.of("DBIRTH", MACHINE)) > births and online_birth(host),
            timeout=20,
            message="the DBIRTH after the controller returned",
        )
        back = host.count()
        await wait_until(lambda: any(s.kind == "DDATA" for s in host.since(back)), message="data again")

    messages = host.since(mark)
    kinds = [(s.kind, s.device) for s in messages]
    death = kinds.index(("DDEATH", MACHINE))
    birth = kinds.index(("DBIRTH", MACHINE), death)
    assert ("DDATA", MACHINE) not in kinds[death:birth]  # nothing of a dead device
    assert messages[death].payload.timestamp and messages[death].payload.metrics == []
    for seen in messages[:death]:  # the values the source marked Bad went with the death, not as data
        for metric in seen.payload.metrics:
            assert metric.properties.get("Quality", (3, 192))[1] != 0
    assert messages[birth].metric("Status/Connected").value is True  # type: ignore[union-attr]
    assert seq_gaps(host.since(0)) == []
    assert len(host.of("NBIRTH")) == 1  # one session throughout (the NDEATH at the end is the clean stop)
