"""`cnc-gateway sparkplug watch` against a running edge node: births and data, decoded (the README's)."""

from __future__ import annotations

import asyncio
import io
from datetime import UTC, datetime
from pathlib import Path

from gateway.cli.main import build_parser
from gateway.cli.sparkplug import Watcher, watch
from tests.integration.mqtt.conftest import Mosquitto
from tests.integration.sparkplug.conftest import sink_rig, sparkplug_config, typed_mapping
from tests.waiting import wait_until


async def test_watch_asks_for_the_births_and_prints_data_by_name(
    mosquitto: Mosquitto, tmp_path: Path
) -> None:
    async with sink_rig(tmp_path, typed_mapping(), sparkplug_config(mosquitto.port)) as rig:
        await wait_until(lambda: rig.sink.born, message="the edge node born")  # before the watcher listens
        args = build_parser().parse_args(
            ["sparkplug", "watch", "--port", str(mosquitto.port), "--rebirth", "--count", "3", "--metrics"]
        )
        out = io.StringIO()
        watcher = Watcher(args, out)
        task = asyncio.create_task(watch(args, watcher))
        await wait_until(lambda: rig.sink.births == 2, message="the rebirth the watcher asked for")
        machine = rig.tree.machines["m1"]
        machine.ingest(machine.nodes["Axes/X/Position"], 12.5, datetime.now(UTC))
        await asyncio.wait_for(task, 10)
    lines = out.getvalue().splitlines()
    assert "NBIRTH  cnc-gateway  seq 0    bdSeq 0" in lines[0]
    assert any("DBIRTH  cnc-gateway/m1  seq 1" in line for line in lines)
    assert any("    Feed/Override = null  (UInt16, alias" in line for line in lines)
    assert "DDATA   cnc-gateway/m1  seq 2    Axes/X/Position=12.5" in lines[-1]
