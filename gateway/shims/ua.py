"""asyncua's NodeId, StatusCode, DataValue, Variant and status errors, typed as asyncua takes them.

asyncua annotates the fields of its data classes with its own subclasses of int, str and datetime
(`ua.Int16`, `ua.UInt32`, `ua.String`, `ua.DateTime`, ...) and DataValue's Value as a Variant, yet it
encodes plain ints, strs and datetimes (and wraps a plain Value in a Variant) and passes them so itself.
Building the subclasses would cost an object per value on the hot path and change nothing on the wire.
These names are asyncua's own constructors (the same objects: no wrapper, no call in between), typed
with what they accept at run time.
"""

from __future__ import annotations

from datetime import datetime
from typing import Any, Protocol, cast
from uuid import UUID

from asyncua import ua
from asyncua.ua.uaerrors import UaStatusCodeError


class _NodeIdType(Protocol):
    def __call__(
        self,
        identifier: int | str | bytes | UUID = 0,
        namespace: int = 0,
        nodeidtype: ua.NodeIdType | None = None,
        /,
    ) -> ua.NodeId: ...


class _StatusCodeType(Protocol):
    def __call__(self, value: int = 0, /) -> ua.StatusCode: ...


class _DataValueType(Protocol):
    def __call__(
        self,
        Value: object = None,
        StatusCode: ua.StatusCode | None = ...,
        SourceTimestamp: datetime | None = None,
        ServerTimestamp: datetime | None = None,
        SourcePicoseconds: int | None = None,
        ServerPicoseconds: int | None = None,
    ) -> ua.DataValue: ...


class _VariantType(Protocol):
    def __call__(
        self,
        Value: object = None,
        VariantType: ua.VariantType | None = None,  # None: asyncua guesses it from the value
        Dimensions: list[int] | None = None,
        is_array: bool | None = None,
    ) -> ua.Variant: ...


class _StatusErrorType(Protocol):
    def __call__(self, code: int, /) -> UaStatusCodeError: ...


new_node_id = cast(_NodeIdType, ua.NodeId)
new_status_code = cast(_StatusCodeType, ua.StatusCode)
new_data_value = cast(_DataValueType, ua.DataValue)
new_variant = cast(_VariantType, ua.Variant)
#: UaStatusCodeError(code) gives the subclass asyncua keeps for that code (BadNodeIdUnknown, ...).
new_status_error = cast(_StatusErrorType, UaStatusCodeError)

#: An OPC UA null array (length -1 on the wire), what a scalar's ArrayDimensions is: asyncua encodes None in
#: a list field so, though it annotates those fields as lists only.
NULL_ARRAY = cast("list[Any]", None)
