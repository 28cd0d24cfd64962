"""asyncua's server made lighter on memory: nodes whose constant attributes are equal share them.

(Its other costly habit, a deep copy of every value per subscribed item, is dropped by
gateway/shims/asyncua_server.py's `keep_written_values`, which the simulator uses too.)
"""

from __future__ import annotations

from typing import Any

from asyncua import ua

#: Attributes whose values are the same on thousands of nodes and are replaced, never changed in place,
#: when anything sets them (AddressSpace.set_attribute_value assigns a new DataValue).
SHAREABLE = frozenset(
    {
        ua.AttributeIds.NodeClass,
        ua.AttributeIds.Description,
        ua.AttributeIds.WriteMask,
        ua.AttributeIds.UserWriteMask,
        ua.AttributeIds.DataType,
        ua.AttributeIds.ValueRank,
        ua.AttributeIds.ArrayDimensions,
        ua.AttributeIds.AccessLevel,
        ua.AttributeIds.UserAccessLevel,
        ua.AttributeIds.MinimumSamplingInterval,
        ua.AttributeIds.Historizing,
        ua.AttributeIds.Executable,
        ua.AttributeIds.UserExecutable,
        ua.AttributeIds.EventNotifier,
        ua.AttributeIds.IsAbstract,
        ua.AttributeIds.Symmetric,
        ua.AttributeIds.ContainsNoLoops,
        ua.AttributeIds.AccessLevelEx,
    }
)


class SharedAttributes:
    """Makes nodes whose constant attributes are equal hold one DataValue for each, instead of one apiece.

    asyncua keeps a DataValue, a Variant and a StatusCode per attribute per node:
    about 7.7 KB per variable, most of it the same dozen values (ValueRank -1,
    WriteMask 0, DataType Double, ...) repeated 10,000 times. Attributes are
    replaced, not changed in place, when set, so one shared DataValue is as good
    as many equal ones. Run it on nodes as they are added (the standard namespace
    after `init`, then each batch): what it frees is reused by the next batch, so
    the process never grows to hold all the copies.
    """

    def __init__(self, server: Any) -> None:
        self._nodes: dict[Any, Any] = server.iserver.aspace._nodes
        self._canonical: dict[tuple[Any, ...], Any] = {}

    def share(self, nodeids: Any = None) -> int:
        """Share the constant attributes of these nodes (all if None); how many DataValues were dropped."""
        nodes = self._nodes
        targets = list(nodes.values()) if nodeids is None else [nodes[n] for n in nodeids if n in nodes]
        canonical, dropped = self._canonical, 0
        for node in targets:
            for attribute, held in node.attributes.items():
                if attribute not in SHAREABLE or held.value_callback is not None or held.value is None:
                    continue
                value = held.value
                key = _key(attribute, value)
                if key is None:
                    continue
                shared = canonical.setdefault(key, value)
                if shared is not value:
                    held.value = shared
                    dropped += 1
        return dropped


def _key(attribute: Any, dv: Any) -> tuple[Any, ...] | None:
    """What makes two DataValues of `attribute` interchangeable, or None where it is not simple to say."""
    variant = dv.Value
    if variant is None:
        return None
    value = variant.Value
    if isinstance(value, ua.LocalizedText):
        value = ("LocalizedText", value.Locale, value.Text)
    elif isinstance(value, list):
        if not all(isinstance(v, int) for v in value):
            return None
        value = ("list", *value)
    elif not isinstance(value, (int, float, bool, str, type(None), ua.NodeId)):
        return None
    dims = tuple(variant.Dimensions) if variant.Dimensions is not None else None
    status = dv.StatusCode.value if dv.StatusCode is not None else None
    return (
        attribute,
        type(value),
        value,
        variant.VariantType,
        dims,
        variant.is_array,
        status,
        dv.SourceTimestamp,
        dv.ServerTimestamp,
        dv.SourcePicoseconds,
        dv.ServerPicoseconds,
    )
