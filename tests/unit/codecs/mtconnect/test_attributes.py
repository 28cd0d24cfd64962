"""A DataItem's attributes: one table, which the XML and the JSON /probe and the `path=` filter all follow."""

from __future__ import annotations

import dataclasses
import json
import xml.etree.ElementTree as ET

import pytest

from gateway.codecs.mtconnect.attributes import ATTRIBUTES, PATH_ATTRIBUTES
from gateway.codecs.mtconnect.documents import DocumentInfo, devices_xml
from gateway.codecs.mtconnect.errors import InvalidPath
from gateway.codecs.mtconnect.json_documents import devices_json
from gateway.codecs.mtconnect.model import Catalog, Category, DataItem, Device, Representation
from gateway.codecs.mtconnect.paths import PathIndex, parse_path

FULL = DataItem(
    id="x1",
    category=Category.SAMPLE,
    type="POSITION",
    name="Xact",
    sub_type="ACTUAL",
    units="MILLIMETER",
    native_units="INCH",
    native_scale=25.4,
    significant_digits=4,
    coordinate_system="MACHINE",
    statistic="AVERAGE",
    composition_id="c1",
    representation=Representation.TIME_SERIES,
    discrete=True,
    source="X",
)
CATALOG = Catalog([Device(id="d1", name="m1", uuid="u-1", data_items=(FULL,))])
INFO = DocumentInfo(sender="gw", creation_time="2026-01-01T00:00:00Z", device_model_change_time="x")
SIZES = {"instance_id": 1, "buffer_size": 16, "asset_buffer_size": 4, "asset_count": 0}


def test_every_field_of_a_data_item_but_its_source_is_a_row_of_the_table() -> None:
    fields = {f.name for f in dataclasses.fields(DataItem)} - {"source"}  # <Source> is an element
    assert len(ATTRIBUTES) == len(fields)
    assert all(a.value(FULL) is not None for a in ATTRIBUTES)  # FULL sets each of them


def test_the_xml_and_the_json_probe_write_the_rows_in_the_tables_order() -> None:
    names = [a.name for a in ATTRIBUTES]
    xml = devices_xml(CATALOG, INFO, **SIZES)
    [element] = [e for e in ET.fromstring(xml).iter() if e.tag.endswith("}DataItem")]
    assert list(element.attrib) == names
    document = json.loads(devices_json(CATALOG, INFO, **SIZES))
    [device] = document["MTConnectDevices"]["Devices"]["Device"]
    [item] = device["DataItems"]["DataItem"]
    assert [k for k in item if k != "Source"] == names
    assert element.attrib["nativeScale"] == "25.4" and item["nativeScale"] == 25.4
    assert element.attrib["discrete"] == "true" and item["discrete"] is True


@pytest.mark.parametrize("attribute", [a.name for a in PATH_ATTRIBUTES])
def test_path_tests_every_attribute_the_table_lets_it(attribute: str) -> None:
    [row] = [a for a in ATTRIBUTES if a.name == attribute]
    value = row.value(FULL)
    assert PathIndex(CATALOG).select(parse_path(f'//DataItem[@{attribute}="{value}"]')) == {"x1"}


@pytest.mark.parametrize("attribute", [a.name for a in ATTRIBUTES if not a.path])
def test_path_does_not_test_the_others(attribute: str) -> None:
    [row] = [a for a in ATTRIBUTES if a.name == attribute]
    text = row.xml(row.value(FULL))
    with pytest.raises(InvalidPath):  # as before the table: they select nothing
        PathIndex(CATALOG).select(parse_path(f'//DataItem[@{attribute}="{text}"]'))
