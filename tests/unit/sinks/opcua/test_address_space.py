from __future__ import annotations

from pathlib import Path

import pytest
from asyncua import ua

from gateway.config.loader import load_mapping
from gateway.model.tree import VariableTree
from gateway.sinks.opcua.address_space import (
    ANALOG_ITEM_TYPE,
    BASE_DATA_VARIABLE_TYPE,
    BASE_OBJECT_TYPE,
    FOLDER_TYPE,
    HAS_COMPONENT,
    HAS_PROPERTY,
    OBJECTS_FOLDER,
    ORGANIZES,
    PROPERTY_TYPE,
    AddressSpacePlan,
)

MAPPING = """
machine: m1
description: Test machine
driver: {endpoint: "opc.tcp://127.0.0.1:4841"}
variables:
  - {path: Axes/X/Position, source: "ns=2;s=x", type: Double, unit: mm, range: {min: 0, max: 3000},
     description: Actual X}
  - {path: Axes/X/Target, source: "ns=2;s=t", type: Double, unit: mm, access: readwrite}
  - {path: Axes/Y/Position, source: "ns=2;s=y", type: Double, range: {min: 0, max: 1500}}
  - {path: Feed/Override, source: "ns=2;s=o", type: UInt16, access: readwrite}
  - {path: Laser/Table, source: "ns=2;s=p", type: "Double[]"}
  - {path: Name, source: "ns=2;s=n", type: String, unit: txt}
"""

NS = 2
STATUS_VARIABLES = 6  # Connected, State, LastError, ReconnectCount, LastChange, Endpoint


@pytest.fixture
def tree(tmp_path: Path) -> VariableTree:
    path = tmp_path / "m1.yaml"
    path.write_text(MAPPING)
    return VariableTree([load_mapping(path).definition()])


def by_id(items: list[ua.AddNodesItem]) -> dict[str, ua.AddNodesItem]:
    return {item.RequestedNewNodeId.Identifier: item for item in items}


def test_plan_has_every_node_once_with_parents_first(tree: VariableTree) -> None:
    plan = AddressSpacePlan(NS)
    plan.add_machines(tree.machines.values())
    items = plan.take()
    ids = [item.RequestedNewNodeId for item in items]
    assert len(ids) == len(set(ids))
    # Machines, m1, folders Axes, Axes/X, Axes/Y, Feed, Laser, Status object; 6+6 variables;
    # properties: EU+range on X/Position, EU on X/Target, range on Y/Position
    assert len(items) == 8 + 6 + STATUS_VARIABLES + 4
    seen = {OBJECTS_FOLDER}
    for item in items:
        assert item.ParentNodeId in seen, f"{item.RequestedNewNodeId} comes before its parent"
        seen.add(item.RequestedNewNodeId)
    assert plan.owned == set(ids)
    assert plan.take() == []


def test_folders_objects_and_reference_types(tree: VariableTree) -> None:
    plan = AddressSpacePlan(NS)
    plan.add_machines(tree.machines.values())
    items = by_id(plan.take())

    machines = items["Machines"]
    assert (machines.ParentNodeId, machines.ReferenceTypeId, machines.TypeDefinition) == (
        OBJECTS_FOLDER,
        ORGANIZES,
        FOLDER_TYPE,
    )
    machine = items["m1"]
    assert machine.NodeClass == ua.NodeClass.Object
    assert (machine.ParentNodeId, machine.ReferenceTypeId, machine.TypeDefinition) == (
        ua.NodeId("Machines", NS),
        ORGANIZES,
        BASE_OBJECT_TYPE,
    )
    assert machine.NodeAttributes.Description == ua.LocalizedText("Test machine")
    assert machine.BrowseName == ua.QualifiedName("m1", NS)

    axes = items["m1/Axes"]
    assert (axes.ParentNodeId, axes.ReferenceTypeId, axes.TypeDefinition) == (
        ua.NodeId("m1", NS),
        HAS_COMPONENT,
        FOLDER_TYPE,
    )
    x = items["m1/Axes/X"]
    assert (x.ParentNodeId, x.ReferenceTypeId, x.TypeDefinition) == (
        ua.NodeId("m1/Axes", NS),
        ORGANIZES,
        FOLDER_TYPE,
    )
    assert x.NodeAttributes.DisplayName == ua.LocalizedText("X")

    status = items["m1/Status"]
    assert status.NodeClass == ua.NodeClass.Object
    assert status.TypeDefinition == BASE_OBJECT_TYPE, "Status is an Object, not a folder"
    connected = items["m1/Status/Connected"]
    assert (connected.ParentNodeId, connected.ReferenceTypeId) == (ua.NodeId("m1/Status", NS), HAS_COMPONENT)


def test_variables_carry_type_rank_access_and_description(tree: VariableTree) -> None:
    plan = AddressSpacePlan(NS)
    plan.add_machines(tree.machines.values())
    items = by_id(plan.take())
    read, read_write = 1, 3

    pos = items["m1/Axes/X/Position"]
    attrs = pos.NodeAttributes
    assert pos.NodeClass == ua.NodeClass.Variable
    assert (pos.ParentNodeId, pos.ReferenceTypeId) == (ua.NodeId("m1/Axes/X", NS), ORGANIZES)
    assert pos.BrowseName == ua.QualifiedName("Position", NS)
    assert attrs.DisplayName == ua.LocalizedText("Position")
    assert attrs.Description == ua.LocalizedText("Actual X")
    assert attrs.DataType == ua.NodeId(ua.ObjectIds.Double)
    assert (attrs.ValueRank, attrs.ArrayDimensions) == (-1, None)
    assert (attrs.AccessLevel, attrs.UserAccessLevel) == (read, read)
    assert attrs.Value.VariantType == ua.VariantType.Double

    target = items["m1/Axes/X/Target"].NodeAttributes
    assert (target.AccessLevel, target.UserAccessLevel) == (read_write, read_write)

    table = items["m1/Laser/Table"].NodeAttributes
    assert (table.ValueRank, table.ArrayDimensions) == (1, [0])
    assert table.Value.is_array

    connected = items["m1/Status/Connected"].NodeAttributes
    assert connected.DataType == ua.NodeId(ua.ObjectIds.Boolean)
    assert connected.AccessLevel == read, "internal variables are read-only"


def test_analog_items_and_their_properties(tree: VariableTree) -> None:
    plan = AddressSpacePlan(NS)
    plan.add_machines(tree.machines.values())
    items = by_id(plan.take())

    assert items["m1/Axes/X/Position"].TypeDefinition == ANALOG_ITEM_TYPE  # unit and range
    assert items["m1/Axes/X/Target"].TypeDefinition == ANALOG_ITEM_TYPE  # unit only
    assert items["m1/Axes/Y/Position"].TypeDefinition == ANALOG_ITEM_TYPE  # range only
    assert items["m1/Feed/Override"].TypeDefinition == BASE_DATA_VARIABLE_TYPE  # neither
    assert items["m1/Name"].TypeDefinition == BASE_DATA_VARIABLE_TYPE  # a unit, but not numeric

    eu = items["m1/Axes/X/Position/EngineeringUnits"]
    assert (eu.ParentNodeId, eu.ReferenceTypeId, eu.TypeDefinition) == (
        ua.NodeId("m1/Axes/X/Position", NS),
        HAS_PROPERTY,
        PROPERTY_TYPE,
    )
    assert eu.BrowseName == ua.QualifiedName("EngineeringUnits", 0)
    assert eu.NodeAttributes.DataType == ua.NodeId(ua.ObjectIds.EUInformation)
    assert eu.NodeAttributes.Value.Value.DisplayName == ua.LocalizedText("mm")

    rng = items["m1/Axes/X/Position/EURange"]
    assert rng.BrowseName == ua.QualifiedName("EURange", 0)
    assert rng.NodeAttributes.DataType == ua.NodeId(ua.ObjectIds.Range)
    assert rng.NodeAttributes.Value.Value == ua.Range(Low=0.0, High=3000.0)

    assert "m1/Axes/X/Target/EURange" not in items
    assert "m1/Axes/Y/Position/EngineeringUnits" not in items
    assert "m1/Name/EngineeringUnits" not in items


def test_late_variable_brings_only_its_missing_parents(tree: VariableTree) -> None:
    plan = AddressSpacePlan(NS)
    plan.add_machines(tree.machines.values())
    plan.take()
    machine = tree.machines["m1"]
    jobs = machine.add_internal("Jobs/Queue/Length", "UInt32", "Jobs waiting", 0)
    nodeid = plan.add_variable(jobs)
    items = plan.take()
    assert [item.RequestedNewNodeId.Identifier for item in items] == [
        "m1/Jobs",
        "m1/Jobs/Queue",
        "m1/Jobs/Queue/Length",
    ]
    assert items[0].TypeDefinition == BASE_OBJECT_TYPE and items[1].TypeDefinition == FOLDER_TYPE
    assert nodeid == ua.NodeId("m1/Jobs/Queue/Length", NS)
    assert plan.add_variable(jobs) == nodeid and plan.take() == []


def test_node_ids_spell_the_path(tree: VariableTree) -> None:
    plan = AddressSpacePlan(NS)
    node = tree.find("m1", "Axes/X/Position")
    assert plan.variable_id(node) == ua.NodeId("m1/Axes/X/Position", NS)
    assert plan.variable_id(node).to_string() == "ns=2;s=m1/Axes/X/Position"
    assert plan.machine_id("m1") == ua.NodeId("m1", NS)
    assert plan.machines_id == ua.NodeId("Machines", NS)
