"""The agent without HTTP: the tree as devices, values as observations, every document valid (2.4 schemas).

A shop of 20 laser cutters of 500 data items each (tests/mtconnect_shop.py): /probe,
/current, /sample, /assets and MTConnectError documents validate against the official
schemas; the laser profile maps units, words and alarms as the standard wants them.
"""

from __future__ import annotations

import json
import xml.etree.ElementTree as ET
from datetime import UTC, datetime
from typing import Any

from gateway.codecs.mtconnect.documents import namespace
from gateway.model.events import Event
from gateway.model.tree import VariableTree
from gateway.sinks.mtconnect.agent import Agent
from gateway.sinks.mtconnect.config import AgentConfig
from gateway.sinks.mtconnect.profile import build_profile
from tests.mtconnect_shop import shop
from tests.unit.codecs.mtconnect.conftest import assert_valid, schemas  # noqa: F401 - the fixture

NS = {"m": namespace("Streams")}
T1 = datetime(2024, 5, 1, 12, 0, 1, tzinfo=UTC)


def build(machines: int = 2, items: int = 60, buffer_size: int = 1024) -> tuple[VariableTree, Agent]:
    config = shop(machines, items, buffer_size=buffer_size)
    tree = VariableTree(config.definitions())
    assert config.gateway.mtconnect is not None
    profile = build_profile(tree, config.mappings, config.gateway.mtconnect)
    agent = Agent(profile, config.gateway.mtconnect, instance_id=1_714_560_000)
    agent.start([*profile.bindings, *profile.connected])
    return tree, agent


def drain(tree: VariableTree, agent: Agent, sub: Any) -> None:
    agent.feed(sub.take())


def running(tree: VariableTree, agent: Agent, name: str = "laser01") -> None:
    """The machine connected and cutting: every value Good."""
    sub = tree.hub.subscribe("test", every_change=True)
    machine = tree.machines[name]
    values = {"Machine/State": 1, "Machine/Mode": 0, "Feed/Rate": 1500.0, "Laser/On": True,
              "Laser/Power": 2999.5, "Program/Name": "part <A> & co.nc", "Laser/GasPressure": 12.0,
              "Machine/EmergencyStop": False, "Laser/PowerTable": [20.0, 40.0]}  # fmt: skip
    for node in machine.mapped:
        value = values.get(node.path, "text" if str(node.type) == "String" else 1)
        if node.type.array and node.path not in values:
            value = [] if str(node.type) == "String[]" else [1]
        machine.ingest(node, value, T1)
    machine.status.connected()
    drain(tree, agent, sub)
    sub.close()


def observations(document: str) -> dict[str, list[ET.Element]]:
    out: dict[str, list[ET.Element]] = {}
    for group in ET.fromstring(document).iterfind(".//m:ComponentStream/*", NS):
        for element in group:
            out.setdefault(element.get("dataItemId", ""), []).append(element)
    return out


def test_twenty_machines_every_document_kind_validates(schemas: dict[str, Any]) -> None:  # noqa: F811
    tree, agent = build(20, 500, buffer_size=50_000)
    assert len(agent.catalog.items) == 20 * 500
    for index in range(1, 21):
        running(tree, agent, f"laser{index:02d}")
    agent.on_event(Event("laser03", "alarms/active", [
        {"id": "1001", "text": "Soft limit X+", "severity": 700, "class": 3, "active": True},
        {"id": "7", "text": "Door open", "severity": 400, "class": 2, "active": True},
        {"id": "8", "text": "cleared, not acked", "severity": 400, "class": 2, "active": False},
    ]))  # fmt: skip
    assert_valid(schemas, "Devices", agent.answer("/probe").body)
    assert_valid(schemas, "Devices", agent.answer("/laser07/probe").body)
    current = agent.answer("/current").body
    assert_valid(schemas, "Streams", current)
    assert len(observations(current)) == 20 * 500
    assert_valid(schemas, "Streams", agent.answer("/sample?count=5000").body)
    assert_valid(schemas, "Streams", agent.answer("/laser03/current?path=//Controller").body)
    assert_valid(schemas, "Assets", agent.answer("/assets").body)
    for target in ("/nowhere/current", "/sample?from=99999999", "/current?path=//Nothing", "/frob/nicate"):
        answer = agent.answer(target)
        assert answer.status >= 400
        assert_valid(schemas, "Error", answer.body)


def test_the_laser_profile_speaks_mtconnect() -> None:
    tree, agent = build()
    running(tree, agent)
    items = observations(agent.answer("/current").body)
    assert items["laser01.Machine.State"][0].text == "ACTIVE"
    assert items["laser01.Machine.Mode"][0].text == "AUTOMATIC"
    assert items["laser01.Laser.On"][0].text == "ON"
    assert items["laser01.Machine.EmergencyStop"][0].text == "ARMED"
    assert items["laser01.Feed.Rate"][0].text == "25"  # 1500 mm/min is 25 mm/s
    assert items["laser01.Laser.GasPressure"][0].text == "1200000"  # 12 bar in PASCAL
    assert items["laser01.Program.Name"][0].text == "part <A> & co.nc"
    assert items["laser01_avail"][0].text == "AVAILABLE"
    assert items["laser02_avail"][0].text == "UNAVAILABLE"
    probe = agent.answer("/laser01/probe").body
    root = ET.fromstring(probe)
    ns = {"m": namespace("Devices")}
    feed = root.find(".//m:DataItem[@id='laser01.Feed.Rate']", ns)
    assert feed is not None
    assert (feed.get("units"), feed.get("nativeUnits")) == ("MILLIMETER/SECOND", "MILLIMETER/MINUTE")
    x = root.find(".//m:Linear[@name='X']", ns)
    assert x is not None and x.find(".//m:DataItem[@name='Xact']", ns) is not None
    power = root.find(".//m:ProcessPower//m:DataItem[@type='WATTAGE'][@subType='ACTUAL']", ns)
    assert power is not None and power.get("units") == "WATT"


def test_a_lost_controller_makes_its_items_unavailable_and_says_so_in_availability() -> None:
    tree, agent = build()
    running(tree, agent)
    sub = tree.hub.subscribe("test", every_change=True)
    machine = tree.machines["laser01"]
    machine.invalidate("BadNotConnected", "connection refused")
    machine.status.disconnected("connection refused")
    drain(tree, agent, sub)
    items = observations(agent.answer("/laser01/current").body)
    assert items["laser01_avail"][0].text == "UNAVAILABLE"
    assert items["laser01.Axes.X.Position"][0].text == "UNAVAILABLE"
    assert items["laser01_system"][0].tag.endswith("Unavailable")


def test_alarms_become_faults_and_warnings_and_clear_to_normal() -> None:
    tree, agent = build()
    running(tree, agent)
    agent.on_event(Event("laser01", "alarms/active", [
        {"id": "1001", "text": "Soft limit", "severity": 700, "class": 3, "active": True},
        {"id": "7", "text": "Door", "severity": 400, "class": 2, "active": True},
    ]))  # fmt: skip
    system = observations(agent.answer("/laser01/current").body)["laser01_system"]
    got = {(e.tag.rpartition("}")[2], e.get("nativeCode"), e.get("nativeSeverity"), e.text) for e in system}
    assert got == {("Fault", "1001", "3", "Soft limit"), ("Warning", "7", "2", "Door")}
    agent.on_event(Event("laser01", "alarms/active", [
        {"id": "7", "text": "Door", "severity": 400, "class": 2, "active": True},
    ]))  # fmt: skip
    system = observations(agent.answer("/laser01/current").body)["laser01_system"]
    assert [(e.tag.rpartition("}")[2], e.get("nativeCode")) for e in system] == [("Warning", "7")]
    agent.on_event(Event("laser01", "alarms/active", []))
    system = observations(agent.answer("/laser01/current").body)["laser01_system"]
    assert [e.tag.rpartition("}")[2] for e in system] == ["Normal"]
    history = agent.answer("/laser01/sample?path=//Controller&count=1000").body
    cleared = observations(history)["laser01_system"]
    assert ("Normal", "1001") in {(e.tag.rpartition("}")[2], e.get("nativeCode")) for e in cleared}


def test_a_value_the_item_cannot_hold_is_unavailable_and_counted() -> None:
    tree, agent = build()
    running(tree, agent)
    sub = tree.hub.subscribe("test", every_change=True)
    tree.machines["laser01"].ingest(tree.find("laser01", "Machine/State"), 42, T1)  # no word for 42
    drain(tree, agent, sub)
    assert (
        observations(agent.answer("/laser01/current").body)["laser01.Machine.State"][0].text == "UNAVAILABLE"
    )
    assert agent.rejected == 1


def test_sequence_edges_out_of_range_and_wrap() -> None:
    tree, agent = build(1, 60, buffer_size=64)
    running(tree, agent)
    sub = tree.hub.subscribe("test", every_change=True)
    machine = tree.machines["laser01"]
    node = tree.find("laser01", "Axes/X/Position")
    for n in range(200):  # wraps the 64-slot ring a few times
        machine.ingest(node, float(n), T1)
    drain(tree, agent, sub)
    buffer = agent.buffer
    first, nxt = buffer.first_sequence, buffer.next_sequence
    assert nxt - first == 64
    edge = ET.fromstring(agent.answer(f"/sample?from={first}&count=1").body)
    header = edge.find("m:Header", NS)
    assert header is not None and header.get("firstSequence") == str(first)
    assert agent.answer(f"/sample?from={nxt}&count=5").status == 200  # from=next: empty, polling
    for target in (f"/sample?from={first - 1}", f"/sample?from={nxt + 1}", "/sample?count=65",
                   f"/current?at={first - 1}", f"/sample?from={first}&to={first}"):  # fmt: skip
        answer = agent.answer(target)
        assert answer.status == 400 and "OUT_OF_RANGE" in answer.body, target
    last = observations(agent.answer(f"/sample?from={nxt - 1}&count=1").body)
    assert last["laser01.Axes.X.Position"][0].text == "199"


def test_programs_of_the_job_queue_are_file_assets(schemas: dict[str, Any]) -> None:  # noqa: F811
    config = shop(1, 60)
    data = config.machines[0].model_dump(by_alias=True, exclude_none=True)
    data["jobs"] = {"controller": {"host": "127.0.0.1", "folder": "/p"}}
    from gateway.config.mapping import MachineMapping

    mapping = MachineMapping.model_validate(data)
    tree = VariableTree([mapping.definition()])
    profile = build_profile(tree, {mapping.machine: mapping}, AgentConfig())
    agent = Agent(profile, AgentConfig())
    agent.start([*profile.bindings, *profile.connected])
    record = {"id": "J000001", "filename": "part.nc", "size": 120, "sha256": "ab" * 32, "state": "QUEUED",
              "received_at": "2024-05-01T12:00:00+00:00", "machine": "laser01"}  # fmt: skip
    agent.on_event(Event("laser01", "jobs/J000001", record, retain=True))
    answer = agent.answer("/assets")
    assert_valid(schemas, "Assets", answer.body)
    assert 'name="part.nc"' in answer.body and 'assetId="J000001"' in answer.body
    changed = observations(agent.answer("/current").body)["laser01_asset_chg"][0]
    assert (changed.text, changed.get("assetType")) == ("J000001", "File")
    agent.on_event(Event("laser01", "jobs/J000001", None, retain=True))
    assert "J000001" not in agent.answer("/assets").body
    assert 'removed="true"' in agent.answer("/assets?removed=true").body
    assert agent.answer("/asset/J000002").status == 404
    parsed = json.loads(agent.answer("/assets?removed=true", "application/json").body)
    assert parsed["MTConnectAssets"]["Assets"]["File"][0]["assetId"] == "J000001"


def test_alarms_heard_before_the_controller_connects_show_once_it_does() -> None:
    tree, agent = build()
    agent.on_event(Event("laser01", "alarms/active", [
        {"id": "1001", "text": "Soft limit", "severity": 700, "class": 3, "active": True},
    ]))  # fmt: skip
    system = observations(agent.answer("/laser01/current").body)["laser01_system"]
    assert [e.tag.rpartition("}")[2] for e in system] == ["Unavailable"]  # not connected: not known
    running(tree, agent)
    system = observations(agent.answer("/laser01/current").body)["laser01_system"]
    assert [(e.tag.rpartition("}")[2], e.get("nativeCode")) for e in system] == [("Fault", "1001")]
    running(tree, agent, "laser02")  # no alarm heard of: Normal
    system = observations(agent.answer("/laser02/current").body)["laser02_system"]
    assert [e.tag.rpartition("}")[2] for e in system] == ["Normal"]
