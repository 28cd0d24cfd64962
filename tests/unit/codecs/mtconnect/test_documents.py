"""Every document kind validates against the official MTConnect 2.4 schemas, in XML; JSON carries the same."""

from __future__ import annotations

import json
import xml.etree.ElementTree as ET
from typing import Any

import pytest

from gateway.codecs.mtconnect.assets import AssetRejected, make_asset, removed_copy
from gateway.codecs.mtconnect.buffer import ObservationBuffer, entry_xml
from gateway.codecs.mtconnect.documents import (
    DocumentInfo,
    assets_xml,
    devices_xml,
    error_xml,
    namespace,
    streams_body,
    streams_xml,
)
from gateway.codecs.mtconnect.errors import ErrorCode, InvalidPath, ModelError, OutOfRange, RequestError
from gateway.codecs.mtconnect.json_documents import assets_json, devices_json, error_json, streams_json
from gateway.codecs.mtconnect.model import Catalog, Category, DataItem, Device

from .conftest import assert_valid
from .machines import shop

T0 = "2024-05-01T12:00:00.000000Z"
T1 = "2024-05-01T12:00:01.250000Z"
INFO = DocumentInfo(sender="gateway-test", creation_time=T1, device_model_change_time=T0)
NS = {"m": namespace("Streams")}


def started(catalog: Catalog, size: int = 1024) -> ObservationBuffer:
    buffer = ObservationBuffer(catalog, instance_id=1_714_560_000, size=size)
    buffer.add_unavailable(catalog.items, T0)
    return buffer


def busy(buffer: ObservationBuffer) -> None:
    """A laser cutting a part: every kind of observation the agent will serve."""
    add = buffer.add_value
    add("m1_avail", T1, "AVAILABLE")
    add("m1_estop", T1, "ARMED")
    add("m1_asset_chg", T1, "T1.1", asset_type="CuttingTool")
    add("m1_Xpos", T1, 120.125)
    add("m1_Xpos", T1, 121.5)
    add("m1_Xcmd", T1, "121.5")
    add("m1_Xfeed", T1, 250)
    add("m1_exec", T1, "active")
    add("m1_mode", T1, "AUTOMATIC")
    add("m1_program", T1, "PART-01 <rev A> & co")
    add("m1_block", T1, 'G1 X121.5 F1500 ("finish")')
    add("m1_line", T1, 42)
    add("m1_parts", T1, 7.0)
    add("m1_feed_ovr", T1, 100)
    add("m1_pathpos", T1, (121.5, 30.0, -2.0))
    add("m1_power", T1, 2999.5)
    add("m1_power_state", T1, "ON")
    add("m1_vib", T1, [0.1, 0.2, -0.1, 0.0], sample_rate=1000.0)
    add("m1_var1", T1, "tab\tand control \x01 char")
    buffer.add_condition(
        "m1_system", T1, "FAULT", native_code="E42", native_severity="2", text="Laser overheated"
    )
    buffer.add_condition("m1_system", T1, "WARNING", native_code="W7", qualifier="HIGH", text="Gas pressure")
    buffer.add_condition("m1_motion", T1, "NORMAL")
    buffer.add_condition("m1_logic", T1, "FAULT", native_code="P1", condition_id="P1-a")


def parse(document: str) -> ET.Element:
    return ET.fromstring(document.encode("utf-8"))


def observations(root: ET.Element) -> dict[str, list[ET.Element]]:
    out: dict[str, list[ET.Element]] = {}
    for group in root.iterfind(".//m:ComponentStream/*", NS):
        for element in group:
            out.setdefault(element.get("dataItemId", ""), []).append(element)
    return out


# --- MTConnectDevices ---------------------------------------------------------------------------


def test_probe_validates(schemas: dict[str, Any]) -> None:
    catalog = shop(2)
    document = devices_xml(
        catalog, INFO, instance_id=7, buffer_size=131072, asset_buffer_size=1024, asset_count=0
    )
    assert_valid(schemas, "Devices", document)
    root = ET.fromstring(document)
    ns = {"m": namespace("Devices")}
    items = root.findall(".//m:DataItem", ns)
    assert {i.get("id") for i in items} == set(catalog.items)
    x = root.find('.//m:DataItem[@id="m1_Xpos"]', ns)
    assert x is not None
    assert (x.get("category"), x.get("type"), x.get("subType"), x.get("units")) == (
        "SAMPLE",
        "POSITION",
        "ACTUAL",
        "MILLIMETER",
    )
    assert x.findtext("m:Source", namespaces=ns) == "Xact"
    assert root.find('.//m:Linear[@name="X"]', ns) is not None


def test_probe_of_one_device(schemas: dict[str, Any]) -> None:
    catalog = shop(3)
    one = catalog.device("laser2")
    assert one is not None
    document = devices_xml(
        catalog, INFO, instance_id=7, buffer_size=8, asset_buffer_size=1, asset_count=0, devices=[one]
    )
    assert_valid(schemas, "Devices", document)
    assert [d.get("name") for d in ET.fromstring(document).iter(f"{{{namespace('Devices')}}}Device")] == [
        "laser2"
    ]


@pytest.mark.parametrize(
    ("devices", "message"),
    [
        ([], "at least one Device"),
        ([Device("1st", "a", "u")], "not an XML id"),
        ([Device("d", "a", "u", data_items=(DataItem("d", Category.EVENT, "AVAILABILITY"),))], "used twice"),
        ([Device("d1", "a", "u"), Device("d2", "a", "v")], "name 'a' is used twice"),
        (
            [Device("d", "a", "u", data_items=(DataItem("x", Category.EVENT, "lower case"),))],
            "not an MTConnect type",
        ),
    ],
)
def test_a_model_the_schema_would_refuse_is_refused(devices: list[Device], message: str) -> None:
    with pytest.raises(ModelError, match=message):
        Catalog(devices)


# --- MTConnectStreams ---------------------------------------------------------------------------


def test_current_after_start_lists_every_data_item_once_unavailable(schemas: dict[str, Any]) -> None:
    catalog = shop(2)
    buffer = started(catalog)
    entries, window = buffer.current()
    document = streams_xml(catalog, entries, window, INFO)
    assert_valid(schemas, "Streams", document)
    root = parse(document)
    found = observations(root)
    assert set(found) == set(catalog.items)
    assert all(len(v) == 1 for v in found.values())
    texts = {e.text for v in found.values() for e in v if not e.tag.endswith(("Unavailable", "TimeSeries"))}
    assert texts == {"UNAVAILABLE"}
    header = root.find("m:Header", NS)
    assert header is not None
    assert header.get("firstSequence") == "1" and header.get("nextSequence") == str(len(catalog.items) + 1)


def test_current_of_a_busy_machine_validates_and_says_what_happened(schemas: dict[str, Any]) -> None:
    catalog = shop(2)
    buffer = started(catalog)
    busy(buffer)
    entries, window = buffer.current()
    document = streams_xml(catalog, entries, window, INFO)
    assert_valid(schemas, "Streams", document)
    found = observations(parse(document))

    def one(item: str) -> ET.Element:
        assert len(found[item]) == 1, found[item]
        return found[item][0]

    assert one("m1_Xpos").text == "121.5" and one("m1_Xpos").get("subType") == "ACTUAL"
    assert one("m1_exec").text == "ACTIVE"
    assert one("m1_program").text == "PART-01 <rev A> & co"
    assert one("m1_block").text == 'G1 X121.5 F1500 ("finish")'
    assert one("m1_parts").text == "7" and one("m1_line").text == "42"
    assert one("m1_pathpos").text == "121.5 30 -2"
    assert one("m1_asset_chg").get("assetType") == "CuttingTool"
    vib = one("m1_vib")
    assert vib.tag.endswith("DisplacementTimeSeries") and vib.get("sampleCount") == "4"
    assert one("m1_var1").text == "tab\tand control \ufffd char"
    system = [
        (e.tag.split("}")[1], e.get("nativeCode"), e.get("conditionId"), e.text) for e in found["m1_system"]
    ]
    assert system == [("Fault", "E42", "E42", "Laser overheated"), ("Warning", "W7", "W7", "Gas pressure")]
    assert one("m1_logic").get("conditionId") == "P1-a" and one("m1_motion").tag.endswith("Normal")
    assert one("m2_exec").text == "UNAVAILABLE"


def test_sample_validates_in_sequence_order(schemas: dict[str, Any]) -> None:
    catalog = shop(1)
    buffer = started(catalog)
    busy(buffer)
    first = buffer.next_sequence - 23
    result = buffer.sample(from_=first, count=23)
    document = streams_xml(catalog, result.entries, result.window, INFO)
    assert_valid(schemas, "Streams", document)
    root = parse(document)
    xs = [int(e.get("sequence", "0")) for e in observations(root)["m1_Xpos"]]
    assert xs == sorted(xs) and len(xs) == 2
    assert root.find("m:Header", NS).get("nextSequence") == str(buffer.next_sequence)  # type: ignore[union-attr]


def test_a_chunk_renders_each_observation_as_entry_xml_does() -> None:
    """streams_body renders the common observations inline (a streamed chunk's cost): the same text as
    entry_xml for every kind (escaped text, empty values, time series, assets, conditions)."""
    catalog = shop()
    buffer = started(catalog)
    busy(buffer)
    buffer.add_value("m1_program", T1, "")
    entries = list(buffer.sample(None, from_=1, count=1000).entries)
    for e in entries:
        e.xml_cache = None
    inline = streams_body(catalog, entries)
    rendered = [e.xml_cache for e in entries]
    for e in entries:
        e.xml_cache = None
    assert rendered == [entry_xml(e) for e in entries]
    assert inline == streams_body(catalog, entries)  # and the chunk from cached fragments is the same


def test_an_empty_sample_validates(schemas: dict[str, Any]) -> None:
    catalog = shop(1)
    buffer = started(catalog)
    result = buffer.sample(from_=buffer.next_sequence, count=10)
    document = streams_xml(catalog, result.entries, result.window, INFO)
    assert_valid(schemas, "Streams", document)
    assert "<Streams/>" in document


def test_current_of_20_machines_of_500_data_items_validates(schemas: dict[str, Any]) -> None:
    catalog = shop(20, 500)
    assert len(catalog.items) == 10_000
    buffer = started(catalog, size=131_072)
    for device in range(1, 21):
        buffer.add_value(f"m{device}_Xpos", T1, device * 1.5)
        buffer.add_condition(f"m{device}_system", T1, "FAULT", native_code="E1")
    entries, window = buffer.current()
    document = streams_xml(catalog, entries, window, INFO)
    assert_valid(schemas, "Streams", document)
    assert len(observations(parse(document))) == 10_000
    probe = devices_xml(
        catalog, INFO, instance_id=1, buffer_size=131072, asset_buffer_size=1024, asset_count=0
    )
    assert_valid(schemas, "Devices", probe)


# --- MTConnectAssets and MTConnectError ----------------------------------------------------------


def test_assets_validate_and_removed_ones_say_so(schemas: dict[str, Any]) -> None:
    sheet = make_asset(
        "<RawMaterial><Form>SHEET</Form><HasMaterial>true</HasMaterial></RawMaterial>",
        asset_id="S-304-3mm",
        asset_type="RawMaterial",
        timestamp=T0,
        device_uuid="urn:example:laser:1",
    )
    gone = removed_copy(sheet, T1)
    document = assets_xml([sheet, gone], INFO, instance_id=1, asset_buffer_size=1024, asset_count=2)
    assert_valid(schemas, "Assets", document)
    ns = {"m": namespace("Assets")}
    found = ET.fromstring(document).findall("m:Assets/m:RawMaterial", ns)
    assert [(a.get("assetId"), a.get("removed")) for a in found] == [
        ("S-304-3mm", None),
        ("S-304-3mm", "true"),
    ]
    parsed = json.loads(assets_json([sheet], INFO, instance_id=1, asset_buffer_size=1024, asset_count=1))
    material = parsed["MTConnectAssets"]["Assets"]["RawMaterial"][0]
    assert material["assetId"] == "S-304-3mm" and material["Form"] == {"value": "SHEET"}


@pytest.mark.parametrize(
    ("body", "message"),
    [
        ("<RawMaterial><Form>SHEET</Form>", "not well-formed"),
        ("<File/>", "not 'RawMaterial'"),
        ('<!DOCTYPE x [<!ENTITY a "aaaa">]><RawMaterial/>', "DOCTYPE"),
        ("<RawMaterial>" + "x" * (1 << 20) + "</RawMaterial>", "larger than"),
    ],
)
def test_asset_xml_that_cannot_be_served_is_refused(body: str, message: str) -> None:
    with pytest.raises(AssetRejected, match=message):
        make_asset(body, asset_id="a", asset_type="RawMaterial", timestamp=T0)


def test_an_error_document_with_every_code_validates(schemas: dict[str, Any]) -> None:
    errors = [RequestError(code, f"because {code.value.lower()} <&>") for code in ErrorCode]
    errors.append(OutOfRange("from", 1, 5, 9, "'from' must be in [5, 9]"))
    errors.append(InvalidPath("the path '//x[1]' is not supported"))
    document = error_xml(errors, INFO, instance_id=1, buffer_size=131072)
    assert_valid(schemas, "Error", document)
    ns = {"m": namespace("Error")}
    found = ET.fromstring(document).findall("m:Errors/m:Error", ns)
    assert [e.get("errorCode") for e in found] == [c.value for c in ErrorCode] + [
        "OUT_OF_RANGE",
        "INVALID_PATH",
    ]
    assert found[0].text == "because unauthorized <&>"
    parsed = json.loads(error_json(errors[:1], INFO, instance_id=1, buffer_size=8))
    assert parsed["MTConnectError"]["Errors"]["Error"] == [
        {"errorCode": "UNAUTHORIZED", "value": "because unauthorized <&>"}
    ]
    with pytest.raises(ValueError):
        error_xml([], INFO, instance_id=1, buffer_size=8)


# --- JSON ----------------------------------------------------------------------------------------


def test_json_current_has_cppagents_version_2_shape_and_the_same_observations() -> None:
    catalog = shop(2)
    buffer = started(catalog)
    busy(buffer)
    entries, window = buffer.current()
    doc = json.loads(streams_json(catalog, entries, window, INFO))["MTConnectStreams"]
    assert doc["jsonVersion"] == 2 and doc["schemaVersion"] == "2.4"
    assert doc["Header"]["nextSequence"] == window.next_sequence
    assert doc["Header"]["instanceId"] == 1_714_560_000
    streams = doc["Streams"]["DeviceStream"]
    assert [s["name"] for s in streams] == ["laser1", "laser2"]
    by_component = {c["componentId"]: c for c in streams[0]["ComponentStream"]}
    x = by_component["m1_x"]["Samples"]["Position"]
    assert [(o["dataItemId"], o["value"]) for o in x] == [("m1_Xpos", 121.5), ("m1_Xcmd", 121.5)]
    path = by_component["m1_path"]
    assert path["Events"]["Execution"][0]["value"] == "ACTIVE"
    assert path["Events"]["LineNumber"][0]["value"] == 42
    assert path["Samples"]["PathPosition"][0]["value"] == [121.5, 30.0, -2.0]
    assert path["Condition"]["Fault"][0]["conditionId"] == "P1-a"
    system = by_component["m1_ctl"]["Condition"]
    assert system["Fault"][0]["nativeCode"] == "E42" and system["Warning"][0]["qualifier"] == "HIGH"
    seen = {
        (o["dataItemId"], o["sequence"])
        for s in streams
        for c in s["ComponentStream"]
        for category in ("Samples", "Events", "Condition")
        for group in c.get(category, {}).values()
        for o in group
    }
    assert seen == {(e.item_id, e.sequence) for e in entries}


def test_json_empty_streams_and_probe() -> None:
    catalog = shop(1)
    buffer = started(catalog)
    result = buffer.sample(from_=buffer.next_sequence, count=5)
    doc = json.loads(streams_json(catalog, result.entries, result.window, INFO))
    assert doc["MTConnectStreams"]["Streams"] == {}
    probe = json.loads(
        devices_json(catalog, INFO, instance_id=1, buffer_size=8, asset_buffer_size=4, asset_count=0)
    )["MTConnectDevices"]
    device = probe["Devices"]["Device"][0]
    assert device["uuid"] == "urn:example:laser:1" and device["Description"]["manufacturer"] == "Example"
    linear = device["Components"]["Axes"][0]["Components"]["Linear"]
    assert [a["name"] for a in linear] == ["X", "Y", "Z"]
    assert linear[0]["DataItems"]["DataItem"][0]["Source"] == {"value": "Xact"}
    assert probe["Header"]["assetBufferSize"] == 4


@pytest.mark.parametrize("kind", ["Streams", "Devices", "Error"])
def test_the_validators_do_refuse_a_broken_document(schemas: dict[str, Any], kind: str) -> None:
    catalog = shop(1)
    buffer = started(catalog)
    entries, window = buffer.current()
    document = {
        "Streams": lambda: streams_xml(catalog, entries, window, INFO).replace(
            ">UNAVAILABLE</Position>", ">fast</Position>", 1
        ),
        "Devices": lambda: devices_xml(
            catalog, INFO, instance_id=1, buffer_size=8, asset_buffer_size=1, asset_count=0
        ).replace('category="SAMPLE"', 'category="SOMETIMES"', 1),
        "Error": lambda: error_xml(
            [RequestError(ErrorCode.NO_DEVICE, "x")], INFO, instance_id=1, buffer_size=8
        ).replace("NO_DEVICE", "NO_SUCH_CODE"),
    }[kind]()
    assert list(schemas[kind].iter_errors(document))
