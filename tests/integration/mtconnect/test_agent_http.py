"""The agent over real HTTP: every document kind it serves is valid MTConnect 2.4, and sequences behave.

A gateway's agent face with 20 laser cutters of 500 data items (tests/mtconnect_shop.py),
fed through the tree as a source would feed it, answering an aiohttp client on a free port.
"""

from __future__ import annotations

import asyncio
import json
import xml.etree.ElementTree as ET
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

from gateway.codecs.mtconnect.documents import namespace
from gateway.codecs.mtconnect.responses import parse_streams
from gateway.model.tree import VariableTree
from tests.integration.mtconnect.conftest import agent_sink, assert_valid, fed, schemas, state_config  # noqa: F401

NS = {"m": namespace("Streams")}
T1 = datetime(2024, 5, 1, 12, 0, 1, tzinfo=UTC)


def connect_all(tree: VariableTree) -> None:
    for machine in tree.machines.values():
        for node in machine.mapped:
            spec = str(node.type)
            value: Any = {"String": "text", "Boolean": True, "String[]": [], "Double[]": [1.0]}.get(spec, 1)
            if node.path in ("Machine/State", "Machine/Mode"):
                value = 0
            machine.ingest(node, value, T1)
        machine.status.connected()


def header(document: str) -> dict[str, str]:
    element = ET.fromstring(document).find("m:Header", NS)
    assert element is not None
    return dict(element.attrib)


async def test_twenty_machines_every_document_kind_over_http_validates(
    schemas: dict[str, Any],  # noqa: F811
    tmp_path: Path,
) -> None:
    async with agent_sink(state_config(tmp_path, buffer_size=50_000)) as (tree, sink, http):
        connect_all(tree)
        await fed(sink)
        status, ctype, probe = await http.get("/probe")
        assert (status, ctype.split(";")[0]) == (200, "text/xml")
        assert_valid(schemas, "Devices", probe)
        status, _, current = await http.get("/current")
        assert status == 200 and current.count("dataItemId=") == 20 * 500
        assert_valid(schemas, "Streams", current)
        status, _, sample = await http.get("/laser05/sample?count=1000&path=//Axes")
        assert status == 200
        assert_valid(schemas, "Streams", sample)
        status, _, assets = await http.get("/assets")
        assert status == 200
        assert_valid(schemas, "Assets", assets)
        for target, code in (("/laser99/current", 404), ("/sample?from=0", 400), ("/x/y/z", 400)):
            status, _, error = await http.get(target)
            assert status == code, target
            assert_valid(schemas, "Error", error)
        nxt = int(header(current)["nextSequence"])
        async with http.stream(f"/sample?from={nxt}&interval=50&heartbeat=200&count=1000") as parts:
            machine = tree.machines["laser07"]
            machine.ingest(tree.find("laser07", "Axes/X/Position"), 42.5, T1)
            opening = await anext(parts)  # at once: where the stream starts (empty until something changes)
            assert_valid(schemas, "Streams", opening)
            chunk = opening if "42.5" in opening else await anext(parts)
            assert_valid(schemas, "Streams", chunk)
            assert "42.5" in chunk
            heartbeat = await anext(parts)  # nothing changes: an empty document after 200 ms
            assert_valid(schemas, "Streams", heartbeat)
            assert "<Streams/>" in heartbeat


async def test_a_stream_carries_every_sequence_once_in_order_and_heartbeats_when_quiet(
    tmp_path: Path,
) -> None:
    async with agent_sink(state_config(tmp_path, machines=1, items=60)) as (tree, sink, http):
        connect_all(tree)
        await fed(sink)
        machine = tree.machines["laser01"]
        node = tree.find("laser01", "Axes/X/Position")
        start = sink.agent.buffer.next_sequence
        seen: list[int] = []
        heartbeats = 0
        async with http.stream(f"/sample?from={start}&interval=0&heartbeat=100&count=50") as parts:
            for n in range(300):
                machine.ingest(node, float(n), T1)
                if n % 37 == 0:
                    await asyncio.sleep(0)
            async for part in parts:
                doc = parse_streams(part)
                if not doc.observations:
                    heartbeats += 1
                    if len(seen) >= 300:
                        break
                seen += [o.sequence for o in doc.observations]
        assert seen == list(range(start, start + 300))
        assert heartbeats >= 1


async def test_a_client_that_falls_behind_the_ring_is_told_and_the_stream_ends(
    schemas: dict[str, Any],  # noqa: F811
    tmp_path: Path,
) -> None:
    async with agent_sink(state_config(tmp_path, machines=1, items=60, buffer_size=64)) as (tree, sink, http):
        connect_all(tree)
        await fed(sink)
        machine = tree.machines["laser01"]
        node = tree.find("laser01", "Axes/X/Position")
        start = sink.agent.buffer.first_sequence
        documents: list[str] = []
        async with http.stream(f"/sample?from={start}&interval=500&count=1") as parts:
            documents.append(await anext(parts))  # one observation a half second
            for n in range(200):  # meanwhile the ring turns three times
                machine.ingest(node, float(n), T1)
            documents += [part async for part in parts]
        assert "OUT_OF_RANGE" in documents[-1] and "fell behind" in documents[-1]
        assert_valid(schemas, "Error", documents[-1])


async def test_json_by_accept_header_or_format(tmp_path: Path) -> None:
    async with agent_sink(state_config(tmp_path, machines=1, items=60)) as (tree, _sink, http):
        connect_all(tree)
        status, ctype, text = await http.get("/current", Accept="application/json")
        assert status == 200 and ctype.startswith("application/json")
        assert json.loads(text)["MTConnectStreams"]["jsonVersion"] == 2
        status, ctype, text = await http.get("/probe?format=json")
        assert json.loads(text)["MTConnectDevices"]["Devices"]["Device"][0]["name"] == "laser01"
        status, ctype, text = await http.get("/nowhere/current?format=json")
        assert (
            status == 404
            and json.loads(text)["MTConnectError"]["Errors"]["Error"][0]["errorCode"] == "NO_DEVICE"
        )


async def test_instance_id_and_sequences_after_a_restart_with_and_without_persistence(tmp_path: Path) -> None:
    async def run_once(persist: bool, values: range) -> tuple[int, int, str]:
        config = state_config(
            tmp_path / ("kept" if persist else "memory"), machines=1, items=60, persist=persist
        )
        async with agent_sink(config) as (tree, sink, http):
            connect_all(tree)
            node = tree.find("laser01", "Axes/X/Position")
            for n in values:
                tree.machines["laser01"].ingest(node, float(n), T1)
            await fed(sink)
            _, _, current = await http.get("/current")
        h = header(current)
        return int(h["instanceId"]), int(h["nextSequence"]), current

    first_id, _first_next, _ = await run_once(False, range(10))
    second_id, _second_next, _ = await run_once(False, range(10, 20))
    assert second_id != first_id  # without persistence every start is a new numbering
    kept_id, kept_next, _ = await run_once(True, range(10))
    again_id, again_next, _ = await run_once(True, range(10, 20))
    assert again_id == kept_id and again_next > kept_next  # the numbering goes on
    config = state_config(tmp_path / "kept", machines=1, items=60, persist=True)
    async with agent_sink(config) as (_tree, _sink, http):
        status, _, old = await http.get(
            f"/sample?from={kept_next - 3}&count=3"
        )  # a client's from= still works
        assert status == 200 and header(old)["instanceId"] == str(kept_id)
        assert [o.sequence for o in parse_streams(old).observations] == [
            kept_next - 3,
            kept_next - 2,
            kept_next - 1,
        ]


async def test_an_unclean_stop_starts_a_new_numbering(tmp_path: Path) -> None:
    from gateway.sinks.mtconnect.store import ObservationStore, store_path

    config = state_config(tmp_path, machines=1, items=60, persist=True)
    async with agent_sink(config) as (_tree, _sink, http):
        _, _, first = await http.get("/current")
    store = ObservationStore(store_path(config.state_dir)).open()
    with store._write() as db:  # what a killed process leaves: the file never marked clean
        db.execute("UPDATE meta SET value = '0' WHERE key = 'clean'")
    store.close()
    async with agent_sink(config) as (_tree, _sink, http):
        _, _, second = await http.get("/current")
    assert header(second)["instanceId"] != header(first)["instanceId"]


async def test_streams_that_follow_together_are_sent_the_same_bytes_rendered_once(tmp_path: Path) -> None:
    async with agent_sink(state_config(tmp_path, machines=1, items=60)) as (tree, sink, http):
        connect_all(tree)
        await fed(sink)
        machine = tree.machines["laser01"]
        node = tree.find("laser01", "Axes/X/Position")
        start = sink.agent.buffer.next_sequence
        for n in range(500):
            machine.ingest(node, float(n), T1)
        await fed(sink)
        query = f"/sample?from={start}&interval=100&heartbeat=1000&count=200"
        rendered = sink.server.parts_sent - sink.server.parts_shared
        async with http.stream(query) as first, http.stream(query) as second:
            a = [await anext(first) for _ in range(3)]
            b = [await anext(second) for _ in range(3)]
        assert a == b  # byte for byte, the creation time in each header included
        assert [o.sequence for part in a for o in parse_streams(part).observations] == list(
            range(start, start + 500)
        )
        assert sink.server.parts_sent - sink.server.parts_shared == rendered + 3  # each chunk rendered once


async def test_a_stream_that_does_not_read_holds_up_no_other_and_then_gets_everything(tmp_path: Path) -> None:
    async with agent_sink(state_config(tmp_path, machines=1, items=60)) as (tree, sink, http):
        connect_all(tree)
        await fed(sink)
        machine = tree.machines["laser01"]
        node = tree.find("laser01", "Axes/X/Position")
        start = sink.agent.buffer.next_sequence
        total = 60_000  # about 8 MB of parts: more than the sockets of the stream that does not read hold
        query = f"/sample?from={start}&interval=0&heartbeat=1000&count=1000"
        async with http.stream(query) as stalled, http.stream(query) as reading:
            await anext(stalled)  # started, then never read again
            seen: list[int] = []
            for n in range(total):
                machine.ingest(node, float(n), T1)
                if n % 500 == 0:
                    await asyncio.sleep(0)
            async for part in reading:
                seen += [o.sequence for o in parse_streams(part).observations]
                if len(seen) >= total:
                    break
            assert seen == list(range(start, start + total))
            assert len(sink.server.streams) == 2  # the one that does not read is still open, waiting
            late: list[int] = []
            async for part in stalled:  # and, reading at last, it gets every observation in order
                late += [o.sequence for o in parse_streams(part).observations]
                if len(late) >= total:
                    break
            assert late == seen
