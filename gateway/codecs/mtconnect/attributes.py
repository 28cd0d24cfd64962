"""The attributes of a DataItem, written once: /probe's XML and JSON and the `path=` filter read this table.

(A Description's attributes, the same way: `description_attributes`.)

A row: the attribute's name (the XML attribute and the JSON key, which MTConnect spells alike), its
value on a `DataItem` (None: the attribute is left out), how the XML writes it, and whether a
`path=` test can name it (paths.py keeps those of the probe tree). The JSON writes the value as it
is. The order of the rows is the order in both documents.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator
from dataclasses import dataclass
from typing import Any

from gateway.codecs.mtconnect.model import DataItem, Description, Representation
from gateway.codecs.mtconnect.vocabulary import format_float
from gateway.codecs.mtconnect.xmltext import xml_attr


@dataclass(frozen=True, slots=True)
class Attribute:
    name: str
    value: Callable[[DataItem], Any]  # None: not written
    xml: Callable[[Any], str] = xml_attr  # the text between the quotes
    path: bool = True  # a `path=` test may name it


def _representation(item: DataItem) -> str | None:
    return None if item.representation is Representation.VALUE else item.representation.value


ATTRIBUTES: tuple[Attribute, ...] = (
    Attribute("category", lambda item: item.category.value, str),
    Attribute("id", lambda item: item.id),
    Attribute("type", lambda item: item.type),
    Attribute("name", lambda item: item.name),
    Attribute("subType", lambda item: item.sub_type),
    Attribute("units", lambda item: item.units),
    Attribute("nativeUnits", lambda item: item.native_units),
    Attribute("coordinateSystem", lambda item: item.coordinate_system),
    Attribute("statistic", lambda item: item.statistic),
    Attribute("compositionId", lambda item: item.composition_id),
    Attribute("nativeScale", lambda item: item.native_scale, format_float, path=False),
    Attribute("significantDigits", lambda item: item.significant_digits, str, path=False),
    Attribute("representation", _representation, str),
    Attribute("discrete", lambda item: True if item.discrete else None, lambda _: "true", path=False),
)
PATH_ATTRIBUTES = tuple(a for a in ATTRIBUTES if a.path)


def present(
    item: DataItem, attributes: tuple[Attribute, ...] = ATTRIBUTES
) -> Iterator[tuple[Attribute, Any]]:
    """The item's attributes that are written, with their values, in the documents' order."""
    for attribute in attributes:
        value = attribute.value(item)
        if value is not None:
            yield attribute, value


def description_attributes(d: Description) -> Iterator[tuple[str, str]]:
    """A Description's attributes that are set, in the documents' order (its text is not one)."""
    for name, value in (
        ("manufacturer", d.manufacturer),
        ("model", d.model),
        ("serialNumber", d.serial_number),
        ("station", d.station),
    ):
        if value is not None:
            yield name, value
