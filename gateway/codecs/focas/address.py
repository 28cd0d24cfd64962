"""A FOCAS variable's `source`: what to read (and how), checked at load time.

sysinfo.series         status.run              position.absolute[X]   position.machine (all axes)
feed.actual            spindle.actual          feed.override          spindle.override
program.number         program.main            program.name           program.sequence
program.block          program.select (write)  program.start (write)  parts.count / parts.required
#500  macro:3901       pmc:R100.3  pmc:G12  pmc:D2204:word  pmc:D100:long
param:6711             param:1320[1]           diag:411[2]
alarms.number  alarms.type  alarms.axis  alarms.message  alarms.count   alarm.status
"""

from __future__ import annotations

import re
from dataclasses import dataclass

from gateway.codecs.focas.functions import PMC_AREAS, PMC_BYTE, PMC_LONG, PMC_WORD, POSITION_TYPES
from gateway.codecs.focas.values import STAT_FIELDS
from gateway.errors import AddressError

SYSINFO_FIELDS = ("cnc_type", "mt_type", "series", "version", "axes", "max_axis", "addinfo")
PROGRAM_FIELDS = ("number", "main", "name", "sequence", "block", "select", "start")
ALARM_FIELDS = ("number", "type", "axis", "message", "count")
PARTS = {"count": 3901, "required": 3902}  # the macros a 0i/30i keeps them in
MAX_MACRO = 99_999
MAX_PMC = 65_535
MAX_NUMBER = 99_999
FEED_OVERRIDE = ("G", 12)  # *FV0-7, negative logic: override % = 255 - byte
SPINDLE_OVERRIDE = ("G", 30)  # SOV0-7, in %

_AXIS = r"(?:\[(?P<axis>[A-Za-z][A-Za-z0-9]?|[1-9][0-9]?)\])?"
_RE_MACRO = re.compile(r"^(?:#|macro:)(?P<n>[0-9]{1,5})$")
_RE_PMC = re.compile(
    r"^pmc:(?P<area>[A-Z])(?P<addr>[0-9]{1,5})(?:\.(?P<bit>[0-7]))?(?::(?P<size>byte|word|long))?$"
)
_RE_NUMBERED = re.compile(rf"^(?P<kind>param|diag):(?P<n>[0-9]{{1,5}}){_AXIS}$")
_RE_POSITION = re.compile(rf"^position\.(?P<which>[a-z]+){_AXIS}$")
_RE_DOTTED = re.compile(r"^(?P<group>[a-z_]+)\.(?P<field>[a-z_]+)$")


@dataclass(frozen=True, slots=True)
class Item:
    """One readable (or writable) thing. `kind` picks the function; the rest say which part of its answer."""

    kind: str  # sysinfo status position feed spindle program macro pmc param diag alarms alarm_status
    field: str = ""
    number: int = 0
    axis: str | int | None = None  # a name (X) or a 1-based number; None: all axes (an array)
    area: str = ""
    size: int = PMC_BYTE  # PMC data type
    bit: int | None = None
    inverted: bool = False  # feed override: 255 - the byte

    @property
    def writable(self) -> bool:
        if self.kind == "pmc":
            return self.field != "override"  # the ladder owns the override signals
        return self.kind == "macro" or (self.kind == "program" and self.field in ("select", "start"))

    @property
    def is_array(self) -> bool:
        return (self.kind == "position" and self.axis is None) or (
            self.kind == "alarms" and self.field != "count"
        )


def _axis(text: str | None) -> str | int | None:
    if text is None:
        return None
    return int(text) if text.isdigit() else text.upper()


def parse_address(source: str) -> Item:
    """The item a `source` names; AddressError, saying what would be right, when it names none."""
    s = source.strip()
    if m := _RE_MACRO.match(s):
        n = int(m["n"])
        if not 1 <= n <= MAX_MACRO:
            raise AddressError(f"macro #{n} is outside #1..#{MAX_MACRO}")
        return Item("macro", number=n)
    if m := _RE_PMC.match(s):
        area = m["area"]
        if area not in PMC_AREAS:
            raise AddressError(f"{area!r} is not a PMC area (one of {', '.join(PMC_AREAS)})")
        addr = int(m["addr"])
        size = {"byte": PMC_BYTE, "word": PMC_WORD, "long": PMC_LONG, None: PMC_BYTE}[m["size"]]
        bit = None if m["bit"] is None else int(m["bit"])
        if bit is not None and size != PMC_BYTE:
            raise AddressError(
                f"{source!r}: a bit ({area}{addr}.{bit}) is read from a byte, not a {m['size']}"
            )
        width = {PMC_BYTE: 1, PMC_WORD: 2, PMC_LONG: 4}[size]
        if addr + width - 1 > MAX_PMC:
            raise AddressError(f"{source!r}: PMC address {addr} is beyond {MAX_PMC}")
        if width > 1 and addr % width:
            raise AddressError(f"{source!r}: a {m['size']} starts at an address divisible by {width}")
        return Item("pmc", number=addr, area=area, size=size, bit=bit)
    if m := _RE_NUMBERED.match(s):
        return Item(m["kind"], number=int(m["n"]), axis=_axis(m["axis"]))
    if m := _RE_POSITION.match(s):
        if m["which"] not in POSITION_TYPES:
            raise AddressError(f"{source!r}: a position is one of {', '.join(POSITION_TYPES)}")
        return Item("position", field=m["which"], axis=_axis(m["axis"]))
    if m := _RE_DOTTED.match(s):
        group, field = m["group"], m["field"]
        if group == "sysinfo" and field in SYSINFO_FIELDS:
            return Item("sysinfo", field=field)
        if group == "status" and field in STAT_FIELDS:
            return Item("status", field=field)
        if group in ("feed", "spindle") and field == "actual":
            return Item(group, field=field)
        if group == "feed" and field == "override":
            return Item(
                "pmc", field="override", area=FEED_OVERRIDE[0], number=FEED_OVERRIDE[1], inverted=True
            )
        if group == "spindle" and field == "override":
            return Item("pmc", field="override", area=SPINDLE_OVERRIDE[0], number=SPINDLE_OVERRIDE[1])
        if group == "program" and field in PROGRAM_FIELDS:
            return Item("program", field=field)
        if group == "parts" and field in PARTS:
            return Item("macro", field=field, number=PARTS[field])
        if group == "alarms" and field in ALARM_FIELDS:
            return Item("alarms", field=field)
        if group == "alarm" and field == "status":
            return Item("alarm_status", field=field)
    raise AddressError(
        f"{source!r} is not a FOCAS address: e.g. status.run, position.absolute[X], feed.actual, "
        "program.name, #500, pmc:R100.3, pmc:D2204:word, param:6711, diag:411[1], alarms.message "
        "(docs/focas.md lists them all)"
    )
