"""The gateway's part of the OPC UA address space, as AddNodesItems.

`Objects/Machines/<machine>/<segment>/.../<variable>`: a Machines folder, one Object
per machine, one folder per path segment (an Object for the gateway's own
`Status`/`Jobs`), and the variables at the leaves. Node ids are strings that
spell the path (`ns=2;s=laser-sim/Axes/X/Position`), so they are stable across
restarts and readable in a client.

The plan only produces `ua.AddNodesItem`s; the server module adds them in
batches through asyncua's internal session, which is far faster than one
`add_variable` round per node. Parents always come before their children.
"""

from __future__ import annotations

from collections.abc import Iterable
from functools import cache

from asyncua import ua

from gateway.model.tree import Machine, VariableNode
from gateway.model.types import TypeSpec
from gateway.shims.ua import NULL_ARRAY, new_node_id
from gateway.sinks.opcua.values import (
    SCALAR,
    array_dimensions,
    data_type_id,
    eu_information,
    value_kind,
    value_rank,
)

MACHINES = "Machines"

# The first path segment of a gateway-owned variable becomes an Object under the machine
# (not a folder): "each machine has a Status object". Descriptions of the known ones:
INTERNAL_OBJECTS: dict[str, str] = {
    "Status": "Connection state, last error and counters of the link to the controller",
    "Jobs": "Programs received for this machine and their delivery state",
    "Programs": "The controller's program store: list, fetch, back up, delete and queue programs",
    "Commands": "Commands to the machine",
}

OBJECTS_FOLDER = new_node_id(ua.ObjectIds.ObjectsFolder, 0)
FOLDER_TYPE = new_node_id(ua.ObjectIds.FolderType, 0)
BASE_OBJECT_TYPE = new_node_id(ua.ObjectIds.BaseObjectType, 0)
BASE_DATA_VARIABLE_TYPE = new_node_id(ua.ObjectIds.BaseDataVariableType, 0)
ANALOG_ITEM_TYPE = new_node_id(ua.ObjectIds.AnalogItemType, 0)
PROPERTY_TYPE = new_node_id(ua.ObjectIds.PropertyType, 0)
ORGANIZES = new_node_id(ua.ObjectIds.Organizes, 0)
HAS_COMPONENT = new_node_id(ua.ObjectIds.HasComponent, 0)
HAS_PROPERTY = new_node_id(ua.ObjectIds.HasProperty, 0)
EU_INFORMATION_TYPE = new_node_id(ua.ObjectIds.EUInformation, 0)
RANGE_TYPE = new_node_id(ua.ObjectIds.Range, 0)

READ = ua.AccessLevel.CurrentRead.mask
READ_WRITE = ua.AccessLevel.CurrentRead.mask | ua.AccessLevel.CurrentWrite.mask


def access_level(node: VariableNode) -> int:
    return READ_WRITE if node.definition.writable and not node.internal else READ


def is_analog(node: VariableNode) -> bool:
    spec = node.definition
    return spec.type.is_numeric and bool(spec.unit or spec.range)


class AddressSpacePlan:
    """Tracks which of our nodes exist and yields the AddNodesItems for those that do not yet.

    Folders and objects are created on first use, so a variable added late (a new
    internal variable, a machine added at run time) brings its parents with it.
    """

    def __init__(self, namespace_index: int) -> None:
        self.ns = namespace_index
        self.owned: set[ua.NodeId] = set()
        self.variables: dict[VariableNode, ua.NodeId] = {}
        self._folders: set[str] = set()  # string ids of FolderType containers (children use Organizes)
        self._containers: set[str] = set()
        self._pending: list[ua.AddNodesItem] = []

    # --- ids -------------------------------------------------------------------------------------

    def id(self, text: str) -> ua.NodeId:
        return new_node_id(text, self.ns)

    def machine_id(self, machine: str) -> ua.NodeId:
        return self.id(machine)

    def variable_id(self, node: VariableNode) -> ua.NodeId:
        return self.id(f"{node.machine.name}/{node.path}")

    @property
    def machines_id(self) -> ua.NodeId:
        return self.id(MACHINES)

    # --- planning --------------------------------------------------------------------------------

    def take(self) -> list[ua.AddNodesItem]:
        """The items planned since the last call, parents first."""
        items, self._pending = self._pending, []
        return items

    def add_machines(self, machines: Iterable[Machine]) -> None:
        for machine in machines:
            self.add_machine(machine)
            for node in machine.nodes.values():
                self.add_variable(node)

    def add_machine(self, machine: Machine) -> None:
        if MACHINES not in self._containers:
            self._container(
                MACHINES, OBJECTS_FOLDER, True, MACHINES, "Machines served by this gateway", folder=True
            )
        if machine.name not in self._containers:
            description = machine.definition.description
            self._container(machine.name, self.machines_id, True, machine.name, description, folder=False)

    def add_object(self, machine: Machine, name: str) -> ua.NodeId:
        """An Object directly under the machine (Programs, Commands) that methods hang on."""
        self.add_machine(machine)
        text = f"{machine.name}/{name}"
        if text not in self._containers:
            description = INTERNAL_OBJECTS.get(name, "")
            self._container(text, self.machine_id(machine.name), False, name, description, folder=False)
        return self.id(text)

    def add_item(self, item: ua.AddNodesItem) -> None:
        """Any other node of ours (methods and their argument properties), parents planned first."""
        self._pending.append(item)
        self.owned.add(item.RequestedNewNodeId)

    def add_variable(self, node: VariableNode) -> ua.NodeId:
        """Plan one variable (and any parents still missing); returns its NodeId."""
        existing = self.variables.get(node)
        if existing is not None:
            return existing
        machine = node.machine
        self.add_machine(machine)
        segments = node.path.split("/")
        parent = machine.name
        for depth, segment in enumerate(segments[:-1]):
            text = f"{parent}/{segment}"
            if text not in self._containers:
                internal_object = depth == 0 and node.internal
                description = INTERNAL_OBJECTS.get(segment, "") if internal_object else ""
                self._container(
                    text,
                    self.id(parent),
                    parent in self._folders,
                    segment,
                    description,
                    folder=not internal_object,
                )
            parent = text
        nodeid = self.variable_id(node)
        ref = ORGANIZES if parent in self._folders else HAS_COMPONENT
        self._pending.append(variable_item(nodeid, self.id(parent), ref, segments[-1], self.ns, node))
        self.owned.add(nodeid)
        self.variables[node] = nodeid
        if is_analog(node):
            if node.definition.unit:
                units = eu_information(node.definition.unit)
                self._property(nodeid, "EngineeringUnits", units, EU_INFORMATION_TYPE)
            rng = node.definition.range
            if rng is not None:
                self._property(nodeid, "EURange", ua.Range(Low=rng.min, High=rng.max), RANGE_TYPE)
        return nodeid

    def _container(
        self,
        text: str,
        parent: ua.NodeId,
        parent_is_folder: bool,
        name: str,
        description: str,
        *,
        folder: bool,
    ) -> None:
        nodeid = self.id(text)
        attrs = ua.ObjectAttributes(
            DisplayName=ua.LocalizedText(name),
            Description=ua.LocalizedText(description or None),
            WriteMask=0,
            UserWriteMask=0,
            EventNotifier=0,
        )
        self._pending.append(
            ua.AddNodesItem(
                ParentNodeId=parent,
                ReferenceTypeId=ORGANIZES if parent_is_folder else HAS_COMPONENT,
                RequestedNewNodeId=nodeid,
                BrowseName=ua.QualifiedName(name, self.ns),
                NodeClass=ua.NodeClass.Object,
                NodeAttributes=attrs,
                TypeDefinition=FOLDER_TYPE if folder else BASE_OBJECT_TYPE,
            )
        )
        self._containers.add(text)
        if folder:
            self._folders.add(text)
        self.owned.add(nodeid)

    def _property(self, parent: ua.NodeId, name: str, value: object, data_type: ua.NodeId) -> None:
        nodeid = new_node_id(f"{parent.Identifier!s}/{name}", self.ns)
        attrs = ua.VariableAttributes(
            DisplayName=ua.LocalizedText(name),
            Description=_NO_TEXT,
            WriteMask=0,
            UserWriteMask=0,
            Value=ua.Variant(value, ua.VariantType.ExtensionObject),
            DataType=data_type,
            ValueRank=SCALAR,
            ArrayDimensions=NULL_ARRAY,
            AccessLevel=READ,
            UserAccessLevel=READ,
            MinimumSamplingInterval=0,
            Historizing=False,
        )
        self._pending.append(
            ua.AddNodesItem(
                ParentNodeId=parent,
                ReferenceTypeId=HAS_PROPERTY,
                RequestedNewNodeId=nodeid,
                # Standard properties are named in namespace 0, which is where clients look for them.
                BrowseName=ua.QualifiedName(name, 0),
                NodeClass=ua.NodeClass.Variable,
                NodeAttributes=attrs,
                TypeDefinition=PROPERTY_TYPE,
            )
        )
        self.owned.add(nodeid)


def variable_item(
    nodeid: ua.NodeId, parent: ua.NodeId, ref: ua.NodeId, name: str, ns: int, node: VariableNode
) -> ua.AddNodesItem:
    """The AddNodesItem of one tree variable. Its value starts as the type's neutral value;
    the sink writes the node's real Sample (with its status) right after adding it."""
    spec = node.definition
    type_spec = spec.type
    level = access_level(node)
    attrs = ua.VariableAttributes(
        DisplayName=ua.LocalizedText(name),
        Description=ua.LocalizedText(spec.description) if spec.description else _NO_TEXT,
        WriteMask=0,
        UserWriteMask=0,
        Value=_initial_variant(type_spec),
        DataType=data_type_id(type_spec),
        ValueRank=value_rank(type_spec),
        ArrayDimensions=array_dimensions(type_spec),
        AccessLevel=level,
        UserAccessLevel=level,
        MinimumSamplingInterval=0,
        Historizing=False,
    )
    return ua.AddNodesItem(
        ParentNodeId=parent,
        ReferenceTypeId=ref,
        RequestedNewNodeId=nodeid,
        BrowseName=ua.QualifiedName(name, ns),
        NodeClass=ua.NodeClass.Variable,
        NodeAttributes=attrs,
        TypeDefinition=ANALOG_ITEM_TYPE if is_analog(node) else BASE_DATA_VARIABLE_TYPE,
    )


_NO_TEXT = ua.LocalizedText(None)


@cache
def _initial_variant(spec: TypeSpec) -> ua.Variant:
    """Variants are immutable, so every variable of a type can share its neutral value."""
    return value_kind(spec).variant(spec.default())
