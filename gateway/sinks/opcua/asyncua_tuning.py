"""asyncua's server made lighter on memory: nodes whose constant attributes are equal share their records.

(Its other costly habit, a deep copy of every value per subscribed item, is dropped by
gateway/shims/asyncua_server.py's `keep_written_values`, which the simulator uses too.)
"""

from __future__ import annotations

from typing import Any

from asyncua import ua

from gateway.shims.asyncua_server import SharedAttributeValue, slim_attribute_values

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
    """Makes nodes whose constant attributes are equal hold one record for each, instead of one apiece.

    asyncua keeps a record (AttributeValue), a DataValue, a Variant and a StatusCode per
    attribute per node: about 7.7 KB per variable, most of it the same dozen values
    (ValueRank -1, WriteMask 0, DataType Double, ...) repeated over and over. Equal
    records become one `SharedAttributeValue`, which asyncua copies for a node before it
    changes one (`slim_attribute_values`, installed here if it was not yet). Run it on
    the standard namespace after `init` (the sink's own nodes are built shared, bulk.py,
    and go through here only when built by asyncua's AddNodes).
    """

    def __init__(self, server: Any) -> None:
        slim_attribute_values()  # sharing records is only safe with copy-on-write
        self._nodes: dict[Any, Any] = server.iserver.aspace._nodes
        self._canonical: dict[tuple[Any, ...], SharedAttributeValue] = {}

    def share(self, nodeids: Any = None) -> int:
        """Share the constant attributes of these nodes (all if None); how many records were dropped."""
        nodes = self._nodes
        targets = list(nodes.values()) if nodeids is None else [nodes[n] for n in nodeids if n in nodes]
        canonical, dropped = self._canonical, 0
        for node in targets:
            attributes = node.attributes
            for attribute, held in attributes.items():
                if (
                    attribute not in SHAREABLE
                    or held.value is None
                    or held.value_callback is not None
                    or held.value_setter is not None
                    or held.datachange_callbacks
                ):
                    continue
                key = _key(attribute, held.value)
                if key is None:
                    continue
                shared = canonical.get(key)
                if shared is None:
                    shared = canonical[key] = SharedAttributeValue(held.value)
                if shared is not held:
                    attributes[attribute] = shared  # an existing key: the dict does not change size
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
