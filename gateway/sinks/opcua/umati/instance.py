"""One machine's MachineTool instance, planned as AddNodesItems from the types the server holds.

An instance of a type is its Mandatory InstanceDeclarations, recursively, each with the declaration's
BrowseName, NodeClass, reference type, TypeDefinition, DataType, ValueRank and AccessLevel (model.py says
which they are); Optional ones are added where the mapping fills them (`wanted` paths), and
placeholders (a channel, a laser, a spindle) with a name of the machine's and a type. NodeIds are
strings in the gateway's namespace that spell the path: `umati:<machine>/Monitoring/Channel1/ChannelState`.
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass, field
from typing import Any

from asyncua import ua

from gateway.shims.ua import NULL_ARRAY, new_node_id
from gateway.sinks.opcua.umati.model import Declaration, Space, TypeModel

HAS_COMPONENT = new_node_id(ua.ObjectIds.HasComponent)
ORGANIZES = new_node_id(ua.ObjectIds.Organizes)
READ = ua.AccessLevel.CurrentRead.mask
PREFIX = "umati:"


@dataclass
class Planned:
    """What the plan made: the items (parents first) and each node's id and declared DataType by path."""

    items: list[ua.AddNodesItem] = field(default_factory=list)
    ids: dict[str, ua.NodeId] = field(default_factory=dict)
    data_types: dict[str, ua.NodeId] = field(default_factory=dict)
    type_definitions: dict[str, ua.NodeId] = field(default_factory=dict)


class InstancePlan:
    """Plans one machine's instance: `root`, then `add` for each placeholder below it."""

    def __init__(self, model: TypeModel, space: Space, ns: int, machine: str, wanted: Iterable[str]) -> None:
        self.model = model
        self.space = space
        self.ns = ns
        self.machine = machine
        self.wanted = set(wanted)
        self.prefixes = {"/".join(p.split("/")[:i]) for p in self.wanted for i in range(1, p.count("/") + 2)}
        self.planned = Planned()

    def node_id(self, path: str) -> ua.NodeId:
        text = f"{PREFIX}{self.machine}" + (f"/{path}" if path else "")
        return new_node_id(text, self.ns)

    def root(self, parent: ua.NodeId, type_id: ua.NodeId, name: str) -> ua.NodeId:
        """The machine's instance of `type_id`, Organized by `parent` (the Machinery Machines folder)."""
        nodeid = self.node_id("")
        attrs = ua.ObjectAttributes(DisplayName=ua.LocalizedText(name), EventNotifier=0)
        self._append(
            "",
            nodeid,
            parent,
            ORGANIZES,
            ua.QualifiedName(name, self.ns),
            ua.NodeClass.Object,
            attrs,
            type_id,
        )
        self._children("", nodeid, self.model.type_children(type_id))
        return nodeid

    def add(self, parent_path: str, name: str, type_id: ua.NodeId) -> str:
        """A named instance of `type_id` under an already planned object (a placeholder's instance)."""
        path = f"{parent_path}/{name}"
        nodeid = self.node_id(path)
        attrs = ua.ObjectAttributes(DisplayName=ua.LocalizedText(name), EventNotifier=0)
        bname = ua.QualifiedName(name, self.ns)
        parent = self.planned.ids[parent_path]
        self._append(path, nodeid, parent, HAS_COMPONENT, bname, ua.NodeClass.Object, attrs, type_id)
        self._children(path, nodeid, self.model.type_children(type_id))
        return path

    def _children(self, path: str, nodeid: ua.NodeId, children: dict[str, Declaration]) -> None:
        for name, declaration in children.items():
            child = f"{path}/{name}" if path else name
            if declaration.placeholder or not (declaration.mandatory or child in self.prefixes):
                continue
            if declaration.node_class == ua.NodeClass.Method:
                continue  # methods are served by the types' own nodes; none is mandatory here
            self._declared(child, nodeid, declaration)

    def _declared(self, path: str, parent: ua.NodeId, declaration: Declaration) -> None:
        nodeid = self.node_id(path)
        source = declaration.nodeid
        display = self._value(source, ua.AttributeIds.DisplayName) or ua.LocalizedText(
            declaration.browse_name.Name
        )
        description = self._value(source, ua.AttributeIds.Description)
        attrs: ua.ObjectAttributes | ua.VariableAttributes
        if declaration.node_class == ua.NodeClass.Variable:
            data_type: Any = self._value(source, ua.AttributeIds.DataType)
            rank: Any = self._value(source, ua.AttributeIds.ValueRank)
            dims: Any = self._value(source, ua.AttributeIds.ArrayDimensions)
            value = self.space.attribute(source, ua.AttributeIds.Value)
            attrs = ua.VariableAttributes(
                DisplayName=display,
                Description=description or ua.LocalizedText(None),
                Value=value.Value if value is not None and value.Value is not None else ua.Variant(),
                DataType=data_type,
                ValueRank=-1 if rank is None else rank,
                ArrayDimensions=dims if dims is not None else NULL_ARRAY,
                AccessLevel=READ,
                UserAccessLevel=READ,
                MinimumSamplingInterval=0,
                Historizing=False,
            )
            self.planned.data_types[path] = data_type
        else:
            notifier = self._value(source, ua.AttributeIds.EventNotifier)
            attrs = ua.ObjectAttributes(
                DisplayName=display,
                Description=description or ua.LocalizedText(None),
                EventNotifier=notifier or 0,
            )
        self._append(
            path,
            nodeid,
            parent,
            declaration.reference,
            declaration.browse_name,
            declaration.node_class,
            attrs,
            declaration.type_definition,
        )
        self._children(path, nodeid, self.model.children(declaration))

    def _append(
        self,
        path: str,
        nodeid: ua.NodeId,
        parent: ua.NodeId,
        reference: ua.NodeId,
        bname: ua.QualifiedName,
        node_class: ua.NodeClass,
        attrs: ua.ObjectAttributes | ua.VariableAttributes,
        type_id: ua.NodeId,
    ) -> None:
        self.planned.items.append(
            ua.AddNodesItem(
                ParentNodeId=parent,
                ReferenceTypeId=reference,
                RequestedNewNodeId=nodeid,
                BrowseName=bname,
                NodeClass=node_class,
                NodeAttributes=attrs,
                TypeDefinition=type_id,
            )
        )
        self.planned.ids[path] = nodeid
        self.planned.type_definitions[path] = type_id

    def _value(self, nodeid: ua.NodeId, attribute: ua.AttributeIds) -> object:
        dv = self.space.attribute(nodeid, attribute)
        return None if dv is None or dv.Value is None else dv.Value.Value
