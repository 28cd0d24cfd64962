"""/readyz from every sink's health (gateway/sinks/base.py `Sink.health`), with every sink configured.

The demo's trouble was here: the Sparkplug sink, online with its births published, said `online` where
readiness looked for `connected`, and /readyz answered 503 `{"waiting_for": ["sink sparkplug"]}` for good.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import aiohttp

from tests.integration.mqtt.conftest import Mosquitto
from tests.integration.web.conftest import web_gateway
from tests.waiting import wait_until

EVERY_SINK = {"opcua", "mqtt", "sparkplug", "copydata", "mtconnect", "web"}


def every_sink(broker: Mosquitto) -> dict[str, Any]:
    return {
        "mqtt": {"host": "127.0.0.1", "port": broker.port, "client_id": "readyz-gw"},
        "sparkplug": {"group_id": "shop", "edge_node_id": "readyz"},  # the mqtt: section's broker
        "mtconnect": {"host": "127.0.0.1", "port": 0},
    }


async def readyz(url: str) -> tuple[int, dict[str, Any]]:
    async with aiohttp.ClientSession() as session, session.get(f"{url}/readyz") as r:
        return r.status, await r.json()


async def test_readyz_answers_ready_once_every_sink_is(tmp_path: Path, mosquitto: Mosquitto) -> None:
    async with web_gateway(tmp_path, **every_sink(mosquitto)) as rig:
        assert {s.name for s in rig.gateway.sinks} == EVERY_SINK

        async def ready() -> bool:
            return (await readyz(rig.url)) == (200, {"ready": True, "waiting_for": []})

        await wait_until(ready, timeout=20, message="/readyz 200 with every sink configured")
        health = {s.name: s.health() for s in rig.gateway.sinks}
        assert all(h.ready for h in health.values()), health
        assert health["sparkplug"].state == "online" and health["mqtt"].state == "connected"


async def test_readyz_names_the_sinks_that_lost_their_broker(tmp_path: Path, mosquitto: Mosquitto) -> None:
    async with web_gateway(tmp_path, **every_sink(mosquitto)) as rig:
        await wait_until(
            lambda: all(s.health().ready for s in rig.gateway.sinks), timeout=20, message="every sink"
        )
        mosquitto.stop()

        async def waiting_for_the_broker() -> bool:
            status, body = await readyz(rig.url)
            return status == 503 and {"sink mqtt", "sink sparkplug"} <= set(body["waiting_for"])

        await wait_until(waiting_for_the_broker, timeout=20, message="/readyz 503 naming mqtt and sparkplug")
        _, body = await readyz(rig.url)
        assert not {"sink opcua", "sink copydata", "sink mtconnect", "sink web"} & set(body["waiting_for"])
        assert rig.gateway.sink("mqtt").health().last_error  # why, in the health record

        mosquitto.start()

        async def ready_again() -> bool:
            return (await readyz(rig.url))[0] == 200

        await wait_until(ready_again, timeout=30, message="/readyz 200 once the broker is back")
