"""A mapping file becomes the model's own definitions: what the tree needs, nothing of YAML or pydantic."""

from __future__ import annotations

import pytest

from gateway.config.mapping import MachineMapping
from gateway.model.definitions import MachineDefinition, Range, VariableDefinition
from gateway.model.tree import VariableTree
from gateway.model.types import TypeSpec

MAPPING = {
    "machine": "m1",
    "description": "Test press",
    "driver": {"endpoint": "opc.tcp://plc:4840"},
    "defaults": {"write_role": "engineer"},
    "variables": [
        {
            "path": "Axes/X/Counts",
            "source": "ns=2;s=c",
            "type": "Double",
            "source_type": "Int32",
            "scale": {"gain": 0.001, "offset": 10},
            "access": "readwrite",
            "range": {"min": 0, "max": 200},
            "deadband": "0.5%",
            "unit": "mm",
            "description": "X in mm",
            "role": "operator",
            "mqtt": {"qos": 2},
            "copydata": {"id": 3},
        },
        {"path": "Name", "source": "ns=2;s=n", "type": "String"},
    ],
}


def test_a_mapping_becomes_the_trees_definitions() -> None:
    definition = MachineMapping.model_validate(MAPPING).definition()
    assert definition == MachineDefinition(
        name="m1",
        description="Test press",
        write_role="engineer",
        endpoint="opc.tcp://plc:4840",
        variables=(
            VariableDefinition(
                path="Axes/X/Counts",
                type=TypeSpec.parse("Double"),
                source="ns=2;s=c",
                source_type=TypeSpec.parse("Int32"),
                unit="mm",
                description="X in mm",
                writable=True,
                role="operator",
                gain=0.001,
                offset=10.0,
                deadband=1.0,
                range=Range(0.0, 200.0),
            ),
            VariableDefinition(path="Name", type=TypeSpec.parse("String"), source="ns=2;s=n"),
        ),
    )
    assert definition.variables[0].raw_type == TypeSpec.parse("Int32")
    assert definition.variables[1].raw_type == TypeSpec.parse("String")


def test_the_tree_is_built_from_definitions_alone() -> None:
    tree = VariableTree([MachineMapping.model_validate(MAPPING).definition()])
    m = tree.machines["m1"]
    counts = m.nodes["Axes/X/Counts"]
    assert counts.to_engineering(10_000) == 20.0 and counts.to_raw(20.0) == 10_000
    assert m.write_role(counts) == "operator" and m.write_role(m.nodes["Name"]) == "engineer"
    assert m.nodes["Status/Endpoint"].sample.value == "opc.tcp://plc:4840"


@pytest.mark.parametrize(
    ("kwargs", "fragment"),
    [({"gain": 0.0}, "gain of zero"), ({"deadband": -1.0}, "negative")],
)
def test_a_definition_refuses_what_the_tree_cannot_undo(kwargs: dict[str, float], fragment: str) -> None:
    with pytest.raises(ValueError, match=fragment):
        VariableDefinition("A", TypeSpec.parse("Double"), **kwargs)  # type: ignore[arg-type]


def test_machines_and_variables_defined_twice_are_refused() -> None:
    double = TypeSpec.parse("Double")
    twice = MachineDefinition("m", (VariableDefinition("A", double), VariableDefinition("A", double)))
    with pytest.raises(ValueError, match="defined twice"):
        VariableTree([twice])
    with pytest.raises(ValueError, match="defined twice"):
        VariableTree([MachineDefinition("m", ()), MachineDefinition("m", ())])
