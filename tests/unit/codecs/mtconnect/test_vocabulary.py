"""The vocabulary copied into the codecs agrees with the 2.4 schema files themselves."""

from __future__ import annotations

import xml.etree.ElementTree as ET
from collections import defaultdict
from functools import cache
from pathlib import Path

import pytest

from gateway.codecs.mtconnect.errors import ValueRejected
from gateway.codecs.mtconnect.vocabulary import (
    CONTROLLED,
    DATETIME_EVENTS,
    FLOAT_EVENTS,
    INTEGER_EVENTS,
    THREE_SPACE,
    element_name,
    format_float,
    render_value,
)

from .conftest import schema_dir

XS = "{http://www.w3.org/2001/XMLSchema}"
# Types that are only CONDITION types in 2.4: no Sample or Event element carries them.
CONDITION_ONLY = {"ACTUATOR", "COMMUNICATIONS", "DATA_RANGE", "LOGIC_PROGRAM", "MOTION_PROGRAM", "SYSTEM"}


def _schema(name: str) -> ET.Element:
    directory = schema_dir()
    if directory is None:
        pytest.skip("the MTConnect schemas are not on this machine")
    return ET.parse(Path(directory) / f"MTConnect{name}_2.4_1.0.xsd").getroot()


@cache
def _streams() -> tuple[dict[str, list[str]], dict[str, ET.Element], dict[str, ET.Element]]:
    root = _schema("Streams")
    groups: dict[str, list[str]] = defaultdict(list)
    elements: dict[str, ET.Element] = {}
    for element in root.iter(f"{XS}element"):
        name, group = element.get("name"), element.get("substitutionGroup")
        if name and group:
            groups[group].append(name)
            elements[name] = element
    simple = {s.get("name", ""): s for s in root.iter(f"{XS}simpleType")}
    return groups, elements, simple


@cache
def _types() -> list[str]:
    root = _schema("Devices")
    enum = next(s for s in root.iter(f"{XS}simpleType") if s.get("name") == "DataItemEnumEnum")
    return sorted({e.get("value", "") for e in enum.iter(f"{XS}enumeration")})


def test_every_sample_and_event_type_has_the_element_element_name_gives() -> None:
    _, elements, _ = _streams()
    missing = [t for t in _types() if t not in CONDITION_ONLY and element_name(t) not in elements]
    assert missing == []
    assert element_name("FEATURE_PERSISTENT_ID") == "FeaturePersisitentId"  # the schema's own spelling
    assert element_name("x:LASER_GAS") == "x:LaserGas"


@pytest.mark.parametrize(
    ("group", "ours"),
    [
        ("IntegerEvent", INTEGER_EVENTS),
        ("FloatEvent", FLOAT_EVENTS),
        ("DateTimeEvent", DATETIME_EVENTS),
    ],
)
def test_typed_event_groups_match_the_schema(group: str, ours: frozenset[str]) -> None:
    groups, _, _ = _streams()
    assert {element_name(t) for t in ours} == set(groups[group])


def test_three_space_types_match_the_schema() -> None:
    groups, _, _ = _streams()
    assert {element_name(t) for t in THREE_SPACE} == set(groups["ThreeSpaceSample"]) | set(
        groups["ThreeSpaceEvent"]
    )


def test_controlled_vocabularies_match_the_schema() -> None:
    groups, elements, simple = _streams()
    root = _schema("Streams")
    complex_types = {c.get("name", ""): c for c in root.iter(f"{XS}complexType")}
    schema_sets: dict[str, frozenset[str]] = {}
    type_elements = {element_name(t) for t in _types()}
    for name in groups["Event"]:
        if name not in type_elements:  # abstract bases such as InterfaceEvent
            continue
        complex_type = complex_types.get(elements[name].get("type", ""))
        restriction = (
            None if complex_type is None else complex_type.find(f".//{XS}simpleType/{XS}restriction")
        )
        base = None if restriction is None else simple.get(restriction.get("base", ""))
        if base is None:
            continue
        words = {e.get("value", "") for e in base.iter(f"{XS}enumeration")} - {"UNAVAILABLE"}
        if words:
            schema_sets[name] = frozenset(words)
    assert {element_name(t): words for t, words in CONTROLLED.items()} == schema_sets


@pytest.mark.parametrize(
    ("value", "text"),
    [
        (1.0, "1"),
        (-0.5, "-0.5"),
        (1e20, "1e+20"),
        (float("inf"), "INF"),
        (float("-inf"), "-INF"),
        (float("nan"), "NaN"),
    ],
)
def test_floats_are_xml_schema_floats(value: float, text: str) -> None:
    assert format_float(value) == text


@pytest.mark.parametrize(
    ("category", "kind", "value", "text"),
    [
        ("SAMPLE", "POSITION", "12.50", "12.5"),
        ("SAMPLE", "POSITION", None, "UNAVAILABLE"),
        ("SAMPLE", "POSITION", "unavailable", "UNAVAILABLE"),
        ("EVENT", "EMERGENCY_STOP", "triggered", "TRIGGERED"),
        ("EVENT", "PART_COUNT", "12", "12"),
        ("EVENT", "PROGRAM", 12, "12"),
        ("EVENT", "PROGRAM", True, "true"),
        ("EVENT", "CLOCK_TIME", "2024-05-01T12:00:00Z", "2024-05-01T12:00:00Z"),
        ("EVENT", "ROTATION", [1, 2, 3], "1 2 3"),
    ],
)
def test_render_value(category: str, kind: str, value: object, text: str) -> None:
    assert render_value(category, kind, value) == text  # type: ignore[arg-type]


@pytest.mark.parametrize(
    ("category", "kind", "value"),
    [
        ("SAMPLE", "POSITION", "fast"),
        ("SAMPLE", "PATH_POSITION", "1 2"),
        ("EVENT", "CLOCK_TIME", "yesterday"),
        ("EVENT", "AXIS_FEEDRATE_OVERRIDE", "max"),
        ("EVENT", "AVAILABILITY", "YES"),
    ],
)
def test_render_value_refuses(category: str, kind: str, value: object) -> None:
    with pytest.raises(ValueRejected):
        render_value(category, kind, value)  # type: ignore[arg-type]
