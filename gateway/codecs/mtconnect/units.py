"""Units: the MTConnect units a mapping's `unit` text stands for, and the conversions between them.

MTConnect reports every SAMPLE in one fixed unit per type (a feedrate is MILLIMETER/SECOND, a
temperature CELSIUS), and says what the controller used in `nativeUnits`. Controllers speak
mm/min and bar; the agent converts, as the reference agent does, with `factor(native, units)`:
value_in_units = value_in_native * scale + offset.
"""

from __future__ import annotations

# A mapping's `unit` text (as people write it) -> the MTConnect units name.
NATIVE_NAMES: dict[str, str] = {
    "mm": "MILLIMETER",
    "millimeter": "MILLIMETER",
    "in": "INCH",
    "inch": "INCH",
    "mm/s": "MILLIMETER/SECOND",
    "mm/min": "MILLIMETER/MINUTE",
    "in/min": "INCH/MINUTE",
    "m/min": "METER/MINUTE",
    "deg": "DEGREE",
    "°": "DEGREE",
    "deg/s": "DEGREE/SECOND",
    "deg/min": "DEGREE/MINUTE",
    "rpm": "REVOLUTION/MINUTE",
    "1/min": "REVOLUTION/MINUTE",
    "w": "WATT",
    "kw": "KILOWATT",
    "degc": "CELSIUS",
    "°c": "CELSIUS",
    "c": "CELSIUS",
    "degf": "FAHRENHEIT",
    "°f": "FAHRENHEIT",
    "bar": "BAR",
    "pa": "PASCAL",
    "kpa": "KILOPASCAL",
    "psi": "POUND/INCH^2",
    "%": "PERCENT",
    "s": "SECOND",
    "ms": "MILLISECOND",
    "min": "MINUTE",
    "h": "HOUR",
    "a": "AMPERE",
    "v": "VOLT",
    "hz": "HERTZ",
    "kg": "KILOGRAM",
    "n": "NEWTON",
    "nm": "NEWTON_METER",
    "l": "LITER",
    "l/min": "LITER/MINUTE",
}

# A native unit that MTConnect does not report in -> (the unit it reports in, scale, offset).
_TO_STANDARD: dict[str, tuple[str, float, float]] = {
    "MILLIMETER/MINUTE": ("MILLIMETER/SECOND", 1 / 60, 0.0),
    "METER/MINUTE": ("MILLIMETER/SECOND", 1000 / 60, 0.0),
    "INCH": ("MILLIMETER", 25.4, 0.0),
    "INCH/MINUTE": ("MILLIMETER/SECOND", 25.4 / 60, 0.0),
    "DEGREE/MINUTE": ("DEGREE/SECOND", 1 / 60, 0.0),
    "KILOWATT": ("WATT", 1000.0, 0.0),
    "FAHRENHEIT": ("CELSIUS", 5 / 9, -32 * 5 / 9),
    "BAR": ("PASCAL", 100_000.0, 0.0),
    "KILOPASCAL": ("PASCAL", 1000.0, 0.0),
    "POUND/INCH^2": ("PASCAL", 6894.757293168, 0.0),
    "MILLISECOND": ("SECOND", 0.001, 0.0),
    "MINUTE": ("SECOND", 60.0, 0.0),
    "HOUR": ("SECOND", 3600.0, 0.0),
    "LITER/MINUTE": ("LITER/SECOND", 1 / 60, 0.0),
}


def native_units(unit: str) -> str | None:
    """The MTConnect name of a mapping's `unit` ("mm/min" -> MILLIMETER/MINUTE), or None if unknown."""
    text = unit.strip()
    if not text:
        return None
    known = NATIVE_NAMES.get(text.lower())
    if known is not None:
        return known
    if len(text) > 2 and text.upper() == text and any(c.isalpha() for c in text):  # an MTConnect name
        return text
    return None


def standard_units(native: str) -> str:
    """The unit MTConnect reports a quantity measured in `native` in (itself, if it is one already)."""
    found = _TO_STANDARD.get(native)
    return found[0] if found is not None else native


def factor(native: str | None, units: str | None) -> tuple[float, float]:
    """(scale, offset) from `native` to `units`; (1, 0) when they agree or no conversion is known."""
    if native is None or units is None or native == units:
        return 1.0, 0.0
    found = _TO_STANDARD.get(native)
    if found is not None and found[0] == units:
        return found[1], found[2]
    back = _TO_STANDARD.get(units)
    if back is not None and back[0] == native:
        scale, offset = back[1], back[2]
        return 1 / scale, -offset / scale
    return 1.0, 0.0
