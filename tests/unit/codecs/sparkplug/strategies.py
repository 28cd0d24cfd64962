"""Hypothesis strategies and comparisons shared by the Sparkplug codec tests."""

from __future__ import annotations

import math
from datetime import UTC, datetime, timedelta
from typing import Any

from hypothesis import strategies as st

from gateway.model.types import INT_BOUNDS, DataType, TypeSpec

ALL_SPECS = [TypeSpec(base, array) for base in DataType for array in (False, True)]
EPOCH = datetime(1970, 1, 1, tzinfo=UTC)
_MS = timedelta(milliseconds=1)
_FIRST_MS = (datetime(1, 1, 1, tzinfo=UTC) - EPOCH) // _MS
_LAST_MS = (datetime(9999, 12, 31, 23, 59, 59, 999000, tzinfo=UTC) - EPOCH) // _MS


def datetimes_ms() -> st.SearchStrategy[datetime]:
    """UTC datetimes at millisecond resolution (what Sparkplug carries), years 1 to 9999."""
    return st.integers(_FIRST_MS, _LAST_MS).map(lambda ms: EPOCH + ms * _MS)


def scalars(base: DataType, *, in_array: bool = False) -> st.SearchStrategy[Any]:
    if base is DataType.BOOLEAN:
        return st.booleans()
    if base in INT_BOUNDS:
        lo, hi = INT_BOUNDS[base]
        return st.integers(lo, hi)
    if base is DataType.FLOAT:
        return st.floats(width=32)  # NaN and the infinities included
    if base is DataType.DOUBLE:
        return st.floats()
    if base is DataType.STRING:
        # StringArray elements end at NUL, so they cannot hold one; a String can.
        chars = st.characters(codec="utf-8", exclude_characters="\x00" if in_array else None)
        return st.text(chars, max_size=12)
    return datetimes_ms()


def values(spec: TypeSpec) -> st.SearchStrategy[Any]:
    if spec.array:
        return st.lists(scalars(spec.base, in_array=True), max_size=20)
    return scalars(spec.base)


def same(a: Any, b: Any) -> bool:
    """Equality that treats NaN as equal to NaN and tells -0.0 from 0.0 (and bool from int)."""
    if isinstance(a, list) and isinstance(b, list):
        return len(a) == len(b) and all(same(x, y) for x, y in zip(a, b, strict=True))
    if isinstance(a, float) and isinstance(b, float):
        if math.isnan(a) or math.isnan(b):
            return math.isnan(a) and math.isnan(b)
        return a == b and math.copysign(1, a) == math.copysign(1, b)
    return type(a) is type(b) and a == b
