"""Client writes to the gateway's nodes: OPC UA strictness first, then the tree decides.

A Write to one of our variables is checked the way an OPC UA client expects (the
Variant's type must be the node's, no arrays into scalars, no Bad-status or null
values, only the Value attribute), then handed to `Machine.write_node`, which checks
access, range and roles, unscales, and asks the source. The OPC UA checks run
inside `write_node` (its `check`), after the role check, so that a viewer hears
BadUserAccessDenied whatever it sent and every refusal is audited. The answer's
status name becomes the StatusCode returned to the client. An accepted write
leaves the controller's read-back of the value in the tree (`Machine.write_node`),
which the server puts in the address space before it answers (read-your-writes).
"""

from __future__ import annotations

import logging

from asyncua import ua

from gateway.errors import RequestError, WriteError
from gateway.model.context import WriteContext
from gateway.model.tree import VariableNode
from gateway.shims.ua import new_status_code
from gateway.sinks.opcua.address_space import access_level
from gateway.sinks.opcua.values import ValueKind, status_code

log = logging.getLogger(__name__)

ORIGIN = "opcua"


def _bad(name: str) -> ua.StatusCode:
    return ua.StatusCode(getattr(ua.StatusCodes, name))


def precheck(node: VariableNode, kind: ValueKind, wv: ua.WriteValue) -> ua.StatusCode | None:
    """The StatusCode that refuses this write before the tree sees it, or None to go on."""
    if wv.AttributeId != ua.AttributeIds.Value:
        return _bad("BadNotWritable")
    if not access_level(node) & ua.AccessLevel.CurrentWrite.mask:
        return _bad("BadNotWritable")
    if wv.IndexRange:
        return _bad("BadWriteNotSupported")
    dv = wv.Value
    if dv is None or (dv.StatusCode is not None and dv.StatusCode.is_bad()):
        return _bad("BadTypeMismatch")
    variant = dv.Value
    if variant is None or variant.Value is None or variant.VariantType != kind.vtype:
        return _bad("BadTypeMismatch")
    is_array = bool(variant.is_array) or isinstance(variant.Value, (list, tuple))
    if is_array != kind.spec.array:
        return _bad("BadTypeMismatch")
    if is_array and variant.Dimensions is not None and len(variant.Dimensions) > 1:
        return _bad("BadTypeMismatch")
    return None


_REASONS = {
    "BadNotWritable": "only the Value attribute of {path} can be written",
    "BadWriteNotSupported": "{path}: index ranges cannot be written",
    "BadTypeMismatch": "{path} takes a {type} Variant",
}


def _requested(wv: ua.WriteValue) -> object:
    """The value a client sent, as far as there is one (for the audit trail)."""
    dv = wv.Value
    variant = dv.Value if dv is not None else None
    value = variant.Value if variant is not None else None
    return list(value) if isinstance(value, tuple) else value


async def write_node(
    node: VariableNode, kind: ValueKind, wv: ua.WriteValue, user: str | None, role: str | None = None
) -> ua.StatusCode:
    """Carry out one client write to a tree variable; never raises."""
    value = _requested(wv)

    def check() -> None:
        refused = precheck(node, kind, wv)
        if refused is not None:
            name = refused.name
            reason = _REASONS.get(name, "{path}: refused").format(path=node.full_path, type=kind.spec)
            raise WriteError(reason, status=name)

    try:
        await node.machine.write_node(node, value, WriteContext(ORIGIN, user, role), check=check)
    except RequestError as exc:
        return status_code(exc.status)
    except Exception:
        log.exception("OPC UA write to %s failed unexpectedly", node.full_path)
        return _bad("BadInternalError")
    return new_status_code(ua.StatusCodes.Good)
