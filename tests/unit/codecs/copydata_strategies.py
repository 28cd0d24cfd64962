"""Hypothesis strategies and comparisons shared by the COPYDATA codec tests."""

from __future__ import annotations

import math
from datetime import UTC, datetime
from typing import Any

from hypothesis import strategies as st

from gateway.codecs.copydata import Layout
from gateway.model.types import INT_BOUNDS, DataType, TypeSpec

WIDTHS = (1, 2, 4)
ENCODINGS = ("utf-8", "utf-16-le", "gbk")
ALL_SPECS = [TypeSpec(base, array) for base in DataType for array in (False, True)]

# Kept small so that even a String[] with 1-byte length fields stays under 255 bytes.
MAX_TEXT = 6
MAX_ELEMENTS = 8


def text(encoding: str) -> st.SearchStrategy[str]:
    """Text the encoding can represent, non-ASCII included (gbk: CJK and pinyin letters)."""
    # "utf-8" leaves out lone surrogates, which no encoding here can represent.
    codec = "gbk" if encoding == "gbk" else "utf-8"
    return st.text(st.characters(codec=codec), max_size=MAX_TEXT)


def scalars(base: DataType, encoding: str = "utf-8") -> st.SearchStrategy[Any]:
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
        return text(encoding)
    return st.datetimes(
        min_value=datetime(1601, 1, 1),
        max_value=datetime(9999, 12, 31, 23, 59, 59, 999999),
        timezones=st.just(UTC),
    )


def values(spec: TypeSpec, encoding: str = "utf-8") -> st.SearchStrategy[Any]:
    if spec.array:
        return st.lists(scalars(spec.base, encoding), max_size=MAX_ELEMENTS)
    return scalars(spec.base, encoding)


def layouts() -> st.SearchStrategy[Layout]:
    return st.builds(Layout, st.sampled_from(WIDTHS), st.sampled_from(WIDTHS), st.sampled_from(ENCODINGS))


def same(a: Any, b: Any) -> bool:
    """Equality that treats NaN as equal to NaN and tells -0.0 from 0.0."""
    if isinstance(a, list) and isinstance(b, list):
        return len(a) == len(b) and all(same(x, y) for x, y in zip(a, b, strict=True))
    if isinstance(a, float) and isinstance(b, float):
        if math.isnan(a) or math.isnan(b):
            return math.isnan(a) and math.isnan(b)
        return a == b and math.copysign(1.0, a) == math.copysign(1.0, b)
    return type(a) is type(b) and a == b
