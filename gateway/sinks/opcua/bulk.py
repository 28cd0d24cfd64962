"""Our nodes written straight into asyncua's address space, in bulk, sharing what is equal.

asyncua's `NodeManagementService._add_node` (what AddNodes and the internal
session's `add_nodes` run) costs about a millisecond per variable on these
machines and keeps a fresh copy of everything per node: fifteen DataValues, a
Variant and a StatusCode each, and a ReferenceDescription per reference.
Over 10,000 variables that is the largest part of the sink's start-up and of
its memory. `NodeWriter.add_nodes` produces
the same NodeData (attributes, references on the node and on its parent, in
the same order) from the same AddNodesItems, except that:

* the records of constant attributes (NodeClass, DataType, ValueRank,
  AccessLevel, ... the `asyncua_tuning.SHAREABLE` set) are one
  `SharedAttributeValue` per distinct value, DataValue included, held by every
  node with that value; asyncua gives a node its own copy before it changes
  one (shims/asyncua_server.py `slim_attribute_values`), so clients still see
  each node's own. The Value of every node of one call carries the same
  creation time (asyncua stamps each with its own microsecond; the sink writes
  the real sample right after anyway);
* the reference from a node back to its parent, and to its type definition,
  is one ReferenceDescription per parent and per type, made by asyncua's own
  `_add_reference_no_check` (asyncua replaces these fields, never mutates them
  except to rename a node, which renames every equal copy anyway);
* a parent's existing references are looked at once per call, not once per child.

An item asyncua would refuse (an existing or null node id, a missing parent or
type, a duplicate property) is handed to asyncua itself, so its StatusCode and
its log line stay asyncua's. tests/integration/opcua/test_address_space_identity.py
compares both paths node by node and through a client's Browse and Read.
"""

from __future__ import annotations

from collections.abc import Iterator
from datetime import UTC, datetime
from typing import Any

from asyncua import ua
from asyncua.server.address_space import NodeData

from gateway.shims.asyncua_server import ATTRIBUTE_ORDER, NodeAttributes, SharedAttributeValue
from gateway.shims.ua import new_data_value, new_node_id, new_variant
from gateway.sinks.opcua.asyncua_tuning import SHAREABLE

# The types of asyncua's _add_nodeattributes: attribute name -> (VariantType, is_array); the order in
# which asyncua adds them is the shim's (ATTRIBUTE_ORDER, after NodeId, BrowseName and NodeClass).
_TYPES: dict[str, tuple[ua.VariantType | None, bool]] = {
    "AccessLevel": (ua.VariantType.Byte, False),
    "ArrayDimensions": (ua.VariantType.UInt32, True),
    "BrowseName": (ua.VariantType.QualifiedName, False),
    "ContainsNoLoops": (ua.VariantType.Boolean, False),
    "DataType": (ua.VariantType.NodeId, False),
    "Description": (ua.VariantType.LocalizedText, False),
    "DisplayName": (ua.VariantType.LocalizedText, False),
    "EventNotifier": (ua.VariantType.Byte, False),
    "Executable": (ua.VariantType.Boolean, False),
    "Historizing": (ua.VariantType.Boolean, False),
    "InverseName": (ua.VariantType.LocalizedText, False),
    "IsAbstract": (ua.VariantType.Boolean, False),
    "MinimumSamplingInterval": (ua.VariantType.Double, False),
    "NodeClass": (ua.VariantType.Int32, False),
    "NodeId": (ua.VariantType.NodeId, False),
    "Symmetric": (ua.VariantType.Boolean, False),
    "UserAccessLevel": (ua.VariantType.Byte, False),
    "UserExecutable": (ua.VariantType.Boolean, False),
    "UserWriteMask": (ua.VariantType.UInt32, False),
    "ValueRank": (ua.VariantType.Int32, False),
    "WriteMask": (ua.VariantType.UInt32, False),
    "DataTypeDefinition": (ua.VariantType.ExtensionObject, False),
    "Value": (None, False),
}
_PLAN = tuple(
    (name, *_TYPES[name], getattr(ua.NodeAttributesMask, name), getattr(ua.AttributeIds, name))
    for name in ATTRIBUTE_ORDER
)
_HAS_PROPERTY = new_node_id(ua.ObjectIds.HasProperty)
_GOOD = ua.StatusCode()


class NodeWriter:
    """Adds AddNodesItems to one server's address space as asyncua would, with shared parts."""

    def __init__(self, iserver: Any) -> None:
        self._aspace = iserver.aspace
        self._service = iserver.node_mgt_service
        self._user = iserver.isession.user
        self._attribute_value = _attribute_value()
        self._records: dict[tuple[Any, ...], SharedAttributeValue] = {}
        self._shapes: dict[tuple[tuple[Any, int], ...], dict[Any, Any]] = {}  # NodeAttributes' shared parts
        self._back: dict[tuple[ua.NodeId, ua.NodeId], ua.ReferenceDescription | None] = {}
        self._typedefs: dict[ua.NodeId, ua.ReferenceDescription] = {}

    def try_add_nodes(
        self, items: list[ua.AddNodesItem], user: Any = None, check: bool = True
    ) -> Iterator[Any]:
        """`NodeManagementService.try_add_nodes`: what asyncua's builder of the standard namespace calls
        (with check=False: no time stamps, parents may come later); yields the items not added (yet)."""
        for item, result in zip(items, self.add_nodes(items, check=check), strict=True):
            if not result.StatusCode.is_good():
                yield item

    def add_nodes(self, items: list[ua.AddNodesItem], *, check: bool = True) -> list[ua.AddNodesResult]:
        """One AddNodesResult per item, in order, as `NodeManagementService.add_nodes` answers."""
        aspace = self._aspace
        stamp = datetime.now(UTC) if check else None
        server_stamp = stamp if aspace.force_server_timestamp else None
        known: dict[ua.NodeId, tuple[set[tuple[ua.NodeId, ua.NodeId]], set[str]]] = {}
        results = []
        for item in items:
            nodeid = item.RequestedNewNodeId
            parentid = item.ParentNodeId
            parent = None if parentid.is_null() else aspace.get(parentid)
            typedef = item.TypeDefinition
            seen = None
            if parent is not None:
                seen = known.get(parentid)
                if seen is None:
                    seen = known[parentid] = _references_of(parent)
            if (
                parent is None
                or nodeid.has_null_identifier()
                or nodeid in aspace
                or (seen is not None and item.BrowseName.Name in seen[1])
                or (not typedef.is_null() and typedef not in aspace)
            ):
                results.append(self._service._add_node(item, self._user, check=check))  # asyncua says why
                known.pop(parentid, None)
                continue
            node = NodeData(nodeid)
            self._attributes(node, item, stamp, server_stamp)
            aspace[nodeid] = node
            assert seen is not None
            self._link(node, item, parent, seen, share_back=check)
            if not typedef.is_null():
                node.references.append(self._type_reference(typedef))
            results.append(ua.AddNodesResult(StatusCode=_GOOD, AddedNodeId=nodeid))
        return results

    def _attributes(
        self, node: NodeData, item: ua.AddNodesItem, stamp: datetime | None, server_stamp: datetime | None
    ) -> None:
        """asyncua's _add_node_attributes: NodeId, BrowseName, NodeClass, then every specified one."""
        value_of = self._attribute_value
        # Our nodes (check=True): the node's own records in a NodeAttributes, its constant ones in a dict
        # shared by every node of the same shape, its names as records made when read. The standard
        # namespace's (check=False) are asyncua's dict of records, pickled into its cache as asyncua's
        # builder made them.
        named = stamp is not None
        own: dict[Any, Any] = {} if named else node.attributes
        shared: dict[Any, Any] = {} if named else node.attributes
        display = None
        if not named:
            own[ua.AttributeIds.NodeId] = value_of(
                new_data_value(new_variant(node.nodeid, ua.VariantType.NodeId))
            )
            own[ua.AttributeIds.BrowseName] = value_of(
                new_data_value(new_variant(item.BrowseName, ua.VariantType.QualifiedName))
            )
        shared[ua.AttributeIds.NodeClass] = self._shared(
            ua.AttributeIds.NodeClass, item.NodeClass, ua.VariantType.Int32, False
        )
        given = item.NodeAttributes
        specified = given.SpecifiedAttributes
        for name, vtype, is_array, mask, attribute in _PLAN:
            if not specified & mask:
                continue
            value = getattr(given, name)
            if name == "DataTypeDefinition" and not isinstance(value, ua.DataTypeDefinition):
                dv = new_data_value(new_variant(None, ua.VariantType.Null))
            elif name == "Value":  # the only attribute asyncua stamps with the time it was added
                dv = new_data_value(
                    new_variant(value, vtype, is_array=is_array),
                    SourceTimestamp=stamp,
                    ServerTimestamp=server_stamp,
                )
            elif attribute in SHAREABLE:
                record = self._shared(attribute, value, vtype, is_array)
                (shared if type(record) is SharedAttributeValue else own)[attribute] = record
                continue
            elif named and name == "DisplayName" and isinstance(value, ua.LocalizedText):
                display = value
                continue
            else:
                dv = new_data_value(new_variant(value, vtype, is_array=is_array))
            own[attribute] = value_of(dv)
        if named:
            shape = tuple((attribute, id(record)) for attribute, record in shared.items())
            held = self._shapes.get(shape)
            if held is None:
                held = self._shapes[shape] = shared
            node.attributes = NodeAttributes(own, held, node.nodeid, item.BrowseName, display)

    def _shared(
        self, attribute: ua.AttributeIds, value: Any, vtype: ua.VariantType | None, is_array: bool
    ) -> Any:
        """The record of a constant attribute: one per distinct value, shared by every node that has it
        (a SharedAttributeValue, which asyncua copies before changing it for one node), or a node's own
        where the value is not simple to compare."""
        key = _key(attribute, value, vtype, is_array)
        held = self._records.get(key) if key is not None else None
        if held is None:
            dv = new_data_value(new_variant(value, vtype, is_array=is_array))
            if key is None:
                return self._attribute_value(dv)
            held = self._records[key] = SharedAttributeValue(dv)
        return held

    def _link(
        self,
        node: NodeData,
        item: ua.AddNodesItem,
        parent: NodeData,
        seen: tuple[set[tuple[ua.NodeId, ua.NodeId]], set[str]],
        *,
        share_back: bool,
    ) -> None:
        """asyncua's _add_ref_from_parent and _add_ref_to_parent."""
        reftype, nodeid = item.ReferenceTypeId, node.nodeid
        if (reftype, nodeid) not in seen[0]:
            desc = ua.ReferenceDescription()
            desc.ReferenceTypeId = reftype
            desc.NodeId = nodeid
            desc.NodeClass = item.NodeClass
            desc.BrowseName = item.BrowseName
            desc.DisplayName = item.NodeAttributes.DisplayName
            desc.TypeDefinition = item.TypeDefinition
            desc.IsForward = True
            parent.references.append(desc)
            seen[0].add((reftype, nodeid))
            if reftype == _HAS_PROPERTY:
                seen[1].add(item.BrowseName.Name)
        # One back reference per parent, made once: our parents are complete when their children come.
        # The standard namespace's builder adds references later (PostponeReferences): made each time.
        key = (item.ParentNodeId, reftype)
        if not share_back:
            back = self._made_by_asyncua(item.ParentNodeId, reftype, forward=False, parent=parent)
        else:
            if key not in self._back:
                self._back[key] = self._made_by_asyncua(
                    item.ParentNodeId, reftype, forward=False, parent=parent
                )
            back = self._back[key]
        if back is not None:
            node.references.append(back)

    def _type_reference(self, typedef: ua.NodeId) -> ua.ReferenceDescription:
        desc = self._typedefs.get(typedef)
        if desc is None:
            made = self._made_by_asyncua(typedef, new_node_id(ua.ObjectIds.HasTypeDefinition), forward=True)
            assert made is not None
            desc = self._typedefs[typedef] = made
        return desc

    def _made_by_asyncua(
        self, target: ua.NodeId, reftype: ua.NodeId, *, forward: bool, parent: NodeData | None = None
    ) -> ua.ReferenceDescription | None:
        """The ReferenceDescription asyncua would add to a new node for this reference (None: none)."""
        addref = ua.AddReferencesItem()
        addref.ReferenceTypeId = reftype
        addref.TargetNodeId = target
        addref.IsForward = forward
        if parent is not None:  # _add_ref_to_parent: the parent's NodeClass, or no reference at all
            held = parent.attributes[ua.AttributeIds.NodeClass].value
            if held is None or held.Value is None:
                return None
            addref.TargetNodeClass = held.Value.Value
        else:  # _add_type_definition
            addref.TargetNodeClass = ua.NodeClass.Unspecified
        scratch = NodeData(new_node_id())
        self._service._add_reference_no_check(scratch, addref)
        return scratch.references[0] if scratch.references else None


def _references_of(parent: NodeData) -> tuple[set[tuple[ua.NodeId, ua.NodeId]], set[str]]:
    """A parent's (reference type, target) pairs and the names of its properties, looked at once."""
    pairs, properties = set(), set()
    for ref in parent.references:
        pairs.add((ref.ReferenceTypeId, ref.NodeId))
        if ref.ReferenceTypeId == _HAS_PROPERTY:
            properties.add(ref.BrowseName.Name)
    return pairs, properties


def _attribute_value() -> Any:
    """The AttributeValue class asyncua builds now (shims/asyncua_server.py may have slimmed it)."""
    from asyncua.server import address_space

    return address_space.AttributeValue


def _key(
    attribute: ua.AttributeIds, value: Any, vtype: ua.VariantType | None, is_array: bool
) -> tuple[Any, ...] | None:
    """What makes two constant attributes' DataValues interchangeable (None: not simple to say)."""
    if isinstance(value, ua.LocalizedText):
        plain: Any = ("LocalizedText", value.Locale, value.Text)
    elif isinstance(value, list):
        if not all(type(v) is int for v in value):
            return None
        plain = ("list", *value)
    elif value is None or isinstance(value, (int, float, str, ua.NodeId)):
        plain = value
    else:
        return None
    return (attribute, type(value), plain, vtype, is_array)
