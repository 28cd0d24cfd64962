"""A polled controller's value in the form its variable's controller type wants (FOCAS, Haas MDC).

A protocol that carries numbers without their type (a FOCAS macro is a scaled number, an MDC answer is
text) hands `fit` what it read; `fit` returns it as the mapping's `source_type` (or `type`) wants it,
or raises TypeError with the reason, which the driver shows as BadTypeMismatch.
"""

from __future__ import annotations

from typing import Any

from gateway.model.tree import VariableNode
from gateway.model.types import DataType

_INTEGERS = frozenset(
    {DataType.SBYTE, DataType.BYTE, DataType.INT16, DataType.UINT16, DataType.INT32, DataType.UINT32,
     DataType.INT64, DataType.UINT64}
)  # fmt: skip


def fit(node: VariableNode, value: Any) -> Any:
    """A value as the variable's controller type wants it (an integral macro for an Int32, ...)."""
    spec = node.definition.source_type or node.definition.type
    base = spec.base
    if spec.array:
        if not isinstance(value, list):
            raise TypeError(f"the controller sent one value, the mapping says {spec}")
        return [_scalar(base, v) for v in value]
    if isinstance(value, list):
        raise TypeError(f"the controller sent a list, the mapping says {spec}")
    return _scalar(base, value)


def _scalar(base: DataType, value: Any) -> Any:
    if value is None:
        raise TypeError("the controller has no value (vacant)")
    if base is DataType.STRING:
        return value if isinstance(value, str) else str(value)
    if base is DataType.BOOLEAN:
        return bool(value)
    if base in _INTEGERS:
        if isinstance(value, str):
            raise TypeError(f"the controller sent text, the mapping says {base.value}")
        if isinstance(value, float) and not value.is_integer():
            raise TypeError(f"{value!r} is not an integer, the mapping says {base.value}")
        return int(value)
    if isinstance(value, str):
        raise TypeError(f"the controller sent text, the mapping says {base.value}")
    return float(value)
