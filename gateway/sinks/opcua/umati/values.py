"""A tree variable's sample as a umati node shows it: the DataType the NodeSet declares for that node.

The gateway's own node carries the controller's value in the mapping's type (Machine/State an Int16);
the umati node declares its own (ChannelState an enumeration, FeedOverride a Double, CurrentState a
LocalizedText with its Id and Number). `Converted` makes that DataValue out of the same Sample, with its
status and source timestamp, for `ServerPort.show`; a value the translation has no answer for is shown
BadTypeMismatch (logged once by the server), never a guess.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass
from datetime import datetime
from typing import Any

from asyncua import ua

from gateway.model.sample import Sample
from gateway.shims.ua import new_data_value, new_status_code
from gateway.sinks.opcua.umati.bindings import Bound
from gateway.sinks.opcua.umati.config import Binding, Constant
from gateway.sinks.opcua.umati.model import Space
from gateway.sinks.opcua.values import ValueMismatch, status_code

# Built-in DataTypes of namespace 0 the umati nodes use (and those derived from them), by NodeId number.
VARIANTS: dict[int, ua.VariantType] = {
    ua.ObjectIds.Boolean: ua.VariantType.Boolean,
    ua.ObjectIds.Byte: ua.VariantType.Byte,
    ua.ObjectIds.UInt16: ua.VariantType.UInt16,
    ua.ObjectIds.Int32: ua.VariantType.Int32,
    ua.ObjectIds.UInt32: ua.VariantType.UInt32,
    ua.ObjectIds.Float: ua.VariantType.Float,
    ua.ObjectIds.Double: ua.VariantType.Double,
    ua.ObjectIds.String: ua.VariantType.String,
    ua.ObjectIds.DateTime: ua.VariantType.DateTime,
    ua.ObjectIds.NodeId: ua.VariantType.NodeId,
    ua.ObjectIds.LocalizedText: ua.VariantType.LocalizedText,
    ua.ObjectIds.Duration: ua.VariantType.Double,
    ua.ObjectIds.UtcTime: ua.VariantType.DateTime,
}
_NULL = ua.Variant(None, ua.VariantType.Null)
_MISMATCH = new_status_code(ua.StatusCodes.BadTypeMismatch)
STATE_TYPES = (ua.ObjectIds.StateType, ua.ObjectIds.InitialStateType)


@dataclass(frozen=True)
class State:
    nodeid: ua.NodeId
    number: int


def states(space: Space, machine_type: ua.NodeId) -> dict[str, State]:
    """The states of a state machine type (its StateType components), with their StateNumber."""
    found: dict[str, State] = {}
    for ref in space.references(machine_type):
        if not ref.IsForward or ref.TypeDefinition.NamespaceIndex != 0:
            continue
        if ref.TypeDefinition.Identifier not in STATE_TYPES:
            continue
        number = 0
        for child in space.references(ref.NodeId):
            if child.IsForward and child.BrowseName.Name == "StateNumber":
                dv = space.attribute(child.NodeId, ua.AttributeIds.Value)
                number = int(dv.Value.Value) if dv is not None and dv.Value is not None else 0
        found[str(ref.BrowseName.Name)] = State(ref.NodeId, number)
    return found


def variant_type(data_type: ua.NodeId) -> ua.VariantType:
    """Enumerations (outside namespace 0 here) travel as Int32."""
    if data_type.NamespaceIndex != 0:
        return ua.VariantType.Int32
    return VARIANTS.get(int(data_type.Identifier), ua.VariantType.Variant)


def _cast(vtype: ua.VariantType, value: Any) -> Any:
    if vtype is ua.VariantType.LocalizedText:
        return value if isinstance(value, ua.LocalizedText) else ua.LocalizedText(str(value))
    if vtype is ua.VariantType.String:
        return str(value)
    if vtype is ua.VariantType.Boolean:
        if not isinstance(value, bool):
            raise ValueMismatch(f"expected a Boolean, got {value!r}")
        return value
    if vtype in (ua.VariantType.Double, ua.VariantType.Float):
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise ValueMismatch(f"expected a number, got {value!r}")
        return float(value)
    if vtype in (ua.VariantType.Byte, ua.VariantType.UInt16, ua.VariantType.UInt32, ua.VariantType.Int32):
        if (
            isinstance(value, bool)
            or not isinstance(value, (int, float))
            or (value < 0 and vtype != ua.VariantType.Int32)
        ):
            raise ValueMismatch(f"expected an unsigned integer, got {value!r}")
        return int(value)
    return value


def _enum_index(enum: tuple[str, ...], value: Any) -> int:
    if isinstance(value, str):
        if value not in enum:
            raise ValueMismatch(f"{value!r} is not one of {', '.join(enum)}")
        return enum.index(value)
    if isinstance(value, int) and not isinstance(value, bool) and 0 <= value < len(enum):
        return value
    raise ValueMismatch(f"{value!r} is not a value of the enumeration")


class Converted:
    """`Shown` (port.py): the DataValue of a umati node for a sample of the variable bound to it."""

    __slots__ = ("convert", "vtype")

    def __init__(self, vtype: ua.VariantType, convert: Callable[[Any], Any]) -> None:
        self.vtype = vtype
        self.convert = convert

    @classmethod
    def of(cls, data_type: ua.NodeId, bound: Bound, program_states: Mapping[str, State]) -> Converted:
        source = bound.source
        assert isinstance(source, Binding)
        table = source.values
        factor = source.scale

        def translated(value: Any) -> Any:
            if factor is not None and isinstance(value, (int, float)) and not isinstance(value, bool):
                value = value * factor
            if table is None:
                return value
            key = value
            if key not in table and not isinstance(key, str):
                key = str(key)
            if key not in table:
                raise ValueMismatch(f"{value!r} is not in the umati `values` of {source.variable}")
            return table[key]

        path = bound.path
        if path.endswith("/CurrentState"):
            return cls(
                ua.VariantType.LocalizedText,
                lambda v: ua.LocalizedText(_state(translated(v), program_states)),
            )
        if path.endswith("/CurrentState/Id"):
            return cls(
                ua.VariantType.NodeId, lambda v: program_states[_state(translated(v), program_states)].nodeid
            )
        if path.endswith("/CurrentState/Number"):
            return cls(
                ua.VariantType.UInt32, lambda v: program_states[_state(translated(v), program_states)].number
            )
        vtype = variant_type(data_type)
        enum = bound.enum
        if enum is not None and data_type.NamespaceIndex != 0:
            return cls(vtype, lambda v: _enum_index(enum, translated(v)))
        return cls(vtype, lambda v: _cast(vtype, translated(v)))

    def datavalue(self, sample: Sample, server_ts: datetime) -> ua.DataValue:
        status = status_code(sample.status)
        if status.is_bad():
            variant = _NULL
        else:
            try:
                variant = ua.Variant(self.convert(sample.value), self.vtype)
            except ValueMismatch:
                raise
            except (KeyError, TypeError, ValueError) as exc:
                raise ValueMismatch(str(exc)) from None
        return new_data_value(variant, status, SourceTimestamp=sample.source_ts, ServerTimestamp=server_ts)

    def mismatch(self, sample: Sample, server_ts: datetime) -> ua.DataValue:
        return new_data_value(_NULL, _MISMATCH, SourceTimestamp=sample.source_ts, ServerTimestamp=server_ts)


def _state(value: Any, program_states: Mapping[str, State]) -> str:
    name = str(value)
    if name not in program_states:
        raise ValueMismatch(f"{value!r} is not a state of the ProductionProgramStateMachine")
    return name


def constant_variant(data_type: ua.NodeId, value: Constant, enum: tuple[str, ...] | None) -> ua.Variant:
    """A constant of the mapping as the node's DataType."""
    vtype = variant_type(data_type)
    if enum is not None and data_type.NamespaceIndex != 0:
        return ua.Variant(_enum_index(enum, value), vtype)
    return ua.Variant(_cast(vtype, value), vtype)
