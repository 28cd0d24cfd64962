"""The live socket over real WebSockets against a gateway and simulator: pages watching alike are sent the
same text, a page that does not read holds up no other and gets the latest values once it reads, a change
after a quiet spell still reaches a page, and a page that leaves takes nothing from those that stay.

The values under test are the gateway's own variables, added for the test and set by it (the simulator
moves the mapped ones on its own), so each test knows which value must arrive."""

from __future__ import annotations

import itertools
import json
from collections.abc import AsyncIterator
from typing import Any

import aiohttp
import pytest
import pytest_asyncio

from tests.integration.web.conftest import MACHINE, WebRig, web_gateway
from tests.waiting import wait_until

pytestmark = pytest.mark.asyncio(loop_scope="module")

_names = itertools.count()


@pytest_asyncio.fixture(scope="module", loop_scope="module")
async def live(tmp_path_factory: pytest.TempPathFactory) -> AsyncIterator[WebRig]:
    async with web_gateway(tmp_path_factory.mktemp("web-live")) as rig:
        yield rig


def _variable(rig: WebRig, kind: str = "Double", value: Any = 0.0) -> Any:
    """A variable of the machine's own that only the test sets."""
    return rig.machine.add_internal(f"Test/V{next(_names)}", kind, "set by the test", value)


async def _page(rig: WebRig, *paths: str) -> aiohttp.ClientWebSocketResponse:
    session = await rig.session("vera")
    ws = await session.ws_connect("/api/live")
    await ws.send_str(json.dumps({"watch": [{"machine": MACHINE, "paths": list(paths)}]}))
    return ws


async def _until(ws: aiohttp.ClientWebSocketResponse, path: str, value: Any, timeout: float = 20) -> str:
    """Read until a message carries `value` for `path`; that message's text."""
    while True:
        msg = await ws.receive(timeout=timeout)
        assert msg.type == aiohttp.WSMsgType.TEXT, msg
        rows = json.loads(msg.data).get("v", [])
        if any(r[0] == MACHINE and r[1] == path and r[2] == value for r in rows):
            return str(msg.data)


async def test_pages_watching_alike_are_sent_the_same_text(live: WebRig) -> None:
    node = _variable(live)
    pages = [await _page(live, node.path) for _ in range(3)]
    for ws in pages:
        await _until(ws, node.path, 0.0)  # the snapshot
    live.machine.set_internal(node, 1.5)
    texts = [await _until(ws, node.path, 1.5) for ws in pages]
    assert texts[0] == texts[1] == texts[2]
    assert json.loads(texts[0])["v"][0][:3] == [MACHINE, node.path, 1.5]
    for ws in pages:
        await ws.close()


async def test_a_change_after_a_quiet_spell_reaches_the_page(live: WebRig) -> None:
    node = _variable(live)
    ws = await _page(live, node.path)
    await _until(ws, node.path, 0.0)
    for value in (1.0, 2.0, 3.0):  # each after the page was handed everything: from a quiet start each time
        live.machine.set_internal(node, value)
        await _until(ws, node.path, value)
    await ws.close()


async def test_a_page_that_does_not_read_holds_up_no_other_and_then_gets_the_latest(live: WebRig) -> None:
    blob, probe = _variable(live, "String", ""), _variable(live)
    stalled = await _page(live, blob.path, probe.path)  # never read until the end
    reader = await _page(live, probe.path)
    await _until(reader, probe.path, 0.0)
    big = "x" * (512 * 1024)
    counter = itertools.count(1)

    def behind() -> bool:
        """Feed large values until the gateway holds back (merges) what the stalled page cannot take."""
        live.machine.set_internal(blob, f"{next(counter)}:{big}")
        return any(blob in c.pending for c in live.web.live.clients)

    await wait_until(behind, timeout=30, message="the unread page's socket to fill")
    last = next(counter)
    live.machine.set_internal(blob, f"{last}:{big}")
    live.machine.set_internal(probe, 7.0)
    await _until(reader, probe.path, 7.0)  # the reading page is not held up
    await _until(stalled, blob.path, f"{last}:{big}")  # the stalled page, reading at last, gets the latest
    live.machine.set_internal(probe, 8.0)
    await _until(stalled, probe.path, 8.0)
    await stalled.close()
    await reader.close()


async def test_a_page_that_leaves_takes_nothing_from_a_page_that_stays(live: WebRig) -> None:
    node = _variable(live)
    leaving, staying = await _page(live, node.path), await _page(live, node.path)
    for ws in (leaving, staying):
        await _until(ws, node.path, 0.0)
    open_pages = len(live.web.live.clients)
    await leaving.close()
    await wait_until(lambda: len(live.web.live.clients) == open_pages - 1, message="the gateway to see it go")
    live.machine.set_internal(node, 4.0)
    await _until(staying, node.path, 4.0)
    other = _variable(live)  # and a page watching something else is sent none of it
    third = await _page(live, other.path)
    await _until(third, other.path, 0.0)
    live.machine.set_internal(node, 5.0)
    live.machine.set_internal(other, 6.0)
    text = await _until(third, other.path, 6.0)
    assert node.path not in text
    await _until(staying, node.path, 5.0)
