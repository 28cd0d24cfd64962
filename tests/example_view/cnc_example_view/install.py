"""The example view's nodes, added through the server's port once the tree's nodes exist."""

from __future__ import annotations

from collections.abc import Mapping

from asyncua import ua

from cnc_example_view import ExampleView
from gateway.shims.ua import new_node_id
from gateway.sinks.opcua.port import ServerPort

HAS_COMPONENT = new_node_id(ua.ObjectIds.HasComponent)
BASE_DATA_VARIABLE = new_node_id(ua.ObjectIds.BaseDataVariableType)


class NoteView:
    def __init__(self, machines: Mapping[str, ExampleView]) -> None:
        self.machines = machines

    async def install(self, server: ServerPort) -> None:
        ns = server.namespace_index
        items = []
        for machine, view in self.machines.items():
            attrs = ua.VariableAttributes(
                DisplayName=ua.LocalizedText("Note"),
                Description=ua.LocalizedText(f"About {view.about}"),
                Value=ua.Variant(view.note, ua.VariantType.String),
                DataType=new_node_id(ua.ObjectIds.String),
                ValueRank=-1,
                AccessLevel=ua.AccessLevel.CurrentRead.mask,
                UserAccessLevel=ua.AccessLevel.CurrentRead.mask,
            )
            items.append(
                ua.AddNodesItem(
                    ParentNodeId=server.machine_node_id(machine),
                    ReferenceTypeId=HAS_COMPONENT,
                    RequestedNewNodeId=new_node_id(f"{machine}/Note", ns),
                    BrowseName=ua.QualifiedName("Note", ns),
                    NodeClass=ua.NodeClass.Variable,
                    NodeAttributes=attrs,
                    TypeDefinition=BASE_DATA_VARIABLE,
                )
            )
        await server.add_nodes(items)
