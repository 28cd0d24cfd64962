"""Machine methods (gateway.model.methods) as OPC UA Method nodes: planning and argument checks.

Pure translation over `asyncua.ua` types, no server: the server module adds the
planned nodes and routes calls through `call_result`.

A method `Programs.List` of machine `laser-sim` becomes the Method node
`ns=2;s=laser-sim/Programs/List` under the Object `laser-sim/Programs`, with
`InputArguments`/`OutputArguments` properties typed from the Method's
Arguments, as every OPC UA client expects to find them.

Every call goes through `Machine.call_method`, which checks the session's role
against `Method.role` (BadUserAccessDenied) and audits the call. Inside it, the
arguments are checked the OPC UA way before the handler sees them: too few
arguments -> BadArgumentsMissing, too many -> BadTooManyArguments, a Variant of
the wrong type -> BadTypeMismatch (with the offending argument marked in
InputArgumentResults). A refusal from the handler (a RequestError) becomes its
status code; the outputs are encoded with the declared types.
"""

from __future__ import annotations

import logging
from collections.abc import Iterable, Sequence
from typing import Any

from asyncua import ua

from gateway.errors import CallError, RequestError
from gateway.model.context import WriteContext
from gateway.model.methods import Argument, Method
from gateway.model.tree import Machine
from gateway.shims.ua import new_node_id
from gateway.sinks.opcua.address_space import HAS_COMPONENT, HAS_PROPERTY, PROPERTY_TYPE, AddressSpacePlan
from gateway.sinks.opcua.values import (
    ValueMismatch,
    array_dimensions,
    data_type_id,
    status_code,
    value_kind,
    value_rank,
)

log = logging.getLogger(__name__)

ARGUMENT_TYPE = new_node_id(ua.ObjectIds.Argument, 0)
ORIGIN = "opcua"


def plan_methods(plan: AddressSpacePlan, machines: Iterable[Machine]) -> list[tuple[ua.NodeId, Method]]:
    """Plan every machine's methods (with their objects); returns (method node id, Method) pairs."""
    out = []
    for machine in machines:
        for method in machine.methods.values():
            parent = plan.add_object(machine, method.object)
            nodeid = plan.id(f"{parent.Identifier!s}/{method.name}")
            plan.add_item(method_item(nodeid, parent, method, plan.ns))
            if method.inputs:
                plan.add_item(arguments_item(nodeid, "InputArguments", method.inputs, plan.ns))
            if method.outputs:
                plan.add_item(arguments_item(nodeid, "OutputArguments", method.outputs, plan.ns))
            out.append((nodeid, method))
    return out


def method_item(nodeid: ua.NodeId, parent: ua.NodeId, method: Method, ns: int) -> ua.AddNodesItem:
    attrs = ua.MethodAttributes(
        DisplayName=ua.LocalizedText(method.name),
        Description=ua.LocalizedText(method.description or None),
        WriteMask=0,
        UserWriteMask=0,
        Executable=True,
        UserExecutable=True,
    )
    return ua.AddNodesItem(
        ParentNodeId=parent,
        ReferenceTypeId=HAS_COMPONENT,
        RequestedNewNodeId=nodeid,
        BrowseName=ua.QualifiedName(method.name, ns),
        NodeClass=ua.NodeClass.Method,
        NodeAttributes=attrs,
        TypeDefinition=ua.NodeId(),
    )


def ua_argument(arg: Argument) -> ua.Argument:
    return ua.Argument(
        Name=arg.name,
        DataType=data_type_id(arg.type),
        ValueRank=value_rank(arg.type),
        ArrayDimensions=array_dimensions(arg.type) or [],
        Description=ua.LocalizedText(arg.description or None),
    )


def arguments_item(method_id: ua.NodeId, name: str, args: Sequence[Argument], ns: int) -> ua.AddNodesItem:
    attrs = ua.VariableAttributes(
        DisplayName=ua.LocalizedText(name),
        Description=ua.LocalizedText(None),
        WriteMask=0,
        UserWriteMask=0,
        Value=ua.Variant([ua_argument(a) for a in args], ua.VariantType.ExtensionObject, is_array=True),
        DataType=ARGUMENT_TYPE,
        ValueRank=1,
        ArrayDimensions=[len(args)],
        AccessLevel=ua.AccessLevel.CurrentRead.mask,
        UserAccessLevel=ua.AccessLevel.CurrentRead.mask,
        MinimumSamplingInterval=0,
        Historizing=False,
    )
    return ua.AddNodesItem(
        ParentNodeId=method_id,
        ReferenceTypeId=HAS_PROPERTY,
        RequestedNewNodeId=new_node_id(f"{method_id.Identifier!s}/{name}", ns),
        BrowseName=ua.QualifiedName(name, 0),
        NodeClass=ua.NodeClass.Variable,
        NodeAttributes=attrs,
        TypeDefinition=PROPERTY_TYPE,
    )


def _status(name: str) -> ua.StatusCode:
    return ua.StatusCode(getattr(ua.StatusCodes, name))


def check_inputs(
    method: Method, inputs: Sequence[ua.Variant]
) -> tuple[list[Any] | None, ua.CallMethodResult | None]:
    """The call's input values as Python values, or the CallMethodResult that refuses them."""
    expected = method.inputs
    if len(inputs) < len(expected):
        return None, ua.CallMethodResult(StatusCode=_status("BadArgumentsMissing"))
    if len(inputs) > len(expected):
        return None, ua.CallMethodResult(StatusCode=_status("BadTooManyArguments"))
    results: list[ua.StatusCode] = []
    values: list[Any] = []
    for arg, variant in zip(expected, inputs, strict=True):
        kind = value_kind(arg.type)
        is_array = bool(getattr(variant, "is_array", False)) or isinstance(variant.Value, (list, tuple))
        if (
            variant.VariantType != kind.vtype
            or is_array != arg.type.array
            or (variant.Value is None and not arg.type.array)
        ):
            results.append(_status("BadTypeMismatch"))
            values.append(None)
            continue
        results.append(ua.StatusCode())
        value = variant.Value
        values.append(list(value) if isinstance(value, (list, tuple)) else ([] if value is None else value))
    if any(not r.is_good() for r in results):
        return None, ua.CallMethodResult(StatusCode=_status("BadTypeMismatch"), InputArgumentResults=results)
    return values, None


def encode_outputs(method: Method, outputs: Sequence[Any]) -> list[ua.Variant]:
    """Raises ValueMismatch when a handler returns something its declared outputs cannot carry."""
    if len(outputs) != len(method.outputs):
        raise ValueMismatch(
            f"{method.object}.{method.name} returned {len(outputs)} outputs, declares {len(method.outputs)}"
        )
    return [value_kind(arg.type).variant(value) for arg, value in zip(method.outputs, outputs, strict=True)]


class ArgumentsRefused(CallError):
    """The OPC UA argument check's refusal, carrying the CallMethodResult to answer with."""

    def __init__(self, result: ua.CallMethodResult) -> None:
        code = result.StatusCode
        marked = [i for i, r in enumerate(result.InputArgumentResults or []) if not r.is_good()]
        where = f" (argument {', '.join(str(i + 1) for i in marked)})" if marked else ""
        super().__init__(f"wrong arguments{where}", status=code.name)
        self.result = result


async def call_result(
    machine: Machine, method: Method, inputs: Sequence[ua.Variant], user: str | None, role: str | None = None
) -> ua.CallMethodResult:
    """Carry out one call through `machine.call_method` (role check, audit); never raises."""
    values, refused = check_inputs(method, inputs)

    def check() -> None:
        if refused is not None:
            raise ArgumentsRefused(refused)

    args = values if values is not None else [getattr(v, "Value", v) for v in inputs]
    ok = [ua.StatusCode() for _ in args]
    try:
        outputs = await machine.call_method(method, args, WriteContext(ORIGIN, user, role), check=check)
        variants = encode_outputs(method, outputs)
    except ArgumentsRefused as exc:
        return exc.result
    except RequestError as exc:
        return ua.CallMethodResult(StatusCode=status_code(exc.status), InputArgumentResults=ok)
    except ValueMismatch as exc:
        log.error("OPC UA call %s.%s: %s", method.object, method.name, exc)
        return ua.CallMethodResult(StatusCode=_status("BadInternalError"), InputArgumentResults=ok)
    except Exception:
        log.exception("OPC UA call %s.%s failed unexpectedly", method.object, method.name)
        return ua.CallMethodResult(StatusCode=_status("BadInternalError"), InputArgumentResults=ok)
    return ua.CallMethodResult(StatusCode=ua.StatusCode(), InputArgumentResults=ok, OutputArguments=variants)
