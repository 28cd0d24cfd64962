"""Machine methods as OPC UA Method nodes: the planned nodes, and how a call's arguments are checked."""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import Any

import pytest
from asyncua import ua

from gateway.config.loader import load_mapping
from gateway.errors import InvalidState
from gateway.model.context import WriteContext
from gateway.model.methods import Argument, Method
from gateway.model.tree import VariableTree
from gateway.model.types import TypeSpec
from gateway.sinks.opcua.address_space import BASE_OBJECT_TYPE, HAS_COMPONENT, HAS_PROPERTY, AddressSpacePlan
from gateway.sinks.opcua.methods import call_result, check_inputs, encode_outputs, plan_methods

MAPPING = """
machine: m1
driver: {endpoint: "opc.tcp://127.0.0.1:4841"}
variables:
  - {path: A, source: "ns=2;s=a", type: Double}
"""

calls: list[tuple[str | None, list[Any]]] = []


async def handler(ctx: WriteContext, args: Sequence[Any]) -> Sequence[Any]:
    calls.append((ctx.user, list(args)))
    if args[0] == "busy":
        raise InvalidState("the machine is running")
    if args[0] == "odd":
        return ["not a list"]
    return [[f"{args[0]}.nc", "b.nc"]]


METHOD = Method(
    "Programs",
    "Find",
    "Find programs",
    (Argument("Pattern", TypeSpec.parse("String")), Argument("Limit", TypeSpec.parse("UInt32"))),
    (Argument("Names", TypeSpec.parse("String[]")),),
    handler,
)


@pytest.fixture
def tree(tmp_path: Path) -> VariableTree:
    path = tmp_path / "m1.yaml"
    path.write_text(MAPPING)
    tree = VariableTree([load_mapping(path).definition()])
    tree.machines["m1"].add_method(METHOD)
    return tree


def test_a_method_hangs_on_its_object_with_typed_argument_properties(tree: VariableTree) -> None:
    plan = AddressSpacePlan(2)
    plan.add_machines(tree.machines.values())
    methods = plan_methods(plan, tree.machines.values())
    items = {i.RequestedNewNodeId.Identifier: i for i in plan.take()}
    assert [(n.Identifier, m.name) for n, m in methods] == [("m1/Programs/Find", "Find")]
    obj = items["m1/Programs"]
    assert obj.TypeDefinition == BASE_OBJECT_TYPE and obj.ParentNodeId == ua.NodeId("m1", 2)
    node = items["m1/Programs/Find"]
    assert node.NodeClass == ua.NodeClass.Method and node.ReferenceTypeId == HAS_COMPONENT
    assert node.NodeAttributes.Executable and node.NodeAttributes.UserExecutable
    inputs = items["m1/Programs/Find/InputArguments"]
    assert inputs.ReferenceTypeId == HAS_PROPERTY and inputs.BrowseName == ua.QualifiedName(
        "InputArguments", 0
    )
    args = inputs.NodeAttributes.Value.Value
    assert [(a.Name, a.DataType, a.ValueRank) for a in args] == [
        ("Pattern", ua.NodeId(ua.ObjectIds.String, 0), -1),
        ("Limit", ua.NodeId(ua.ObjectIds.UInt32, 0), -1),
    ]
    outputs = items["m1/Programs/Find/OutputArguments"].NodeAttributes.Value.Value
    assert [(a.Name, a.ValueRank, a.ArrayDimensions) for a in outputs] == [("Names", 1, [0])]
    assert {ua.NodeId("m1/Programs/Find", 2), ua.NodeId("m1/Programs", 2)} <= plan.owned


def s(value: str) -> ua.Variant:
    return ua.Variant(value, ua.VariantType.String)


def u32(value: int) -> ua.Variant:
    return ua.Variant(value, ua.VariantType.UInt32)


@pytest.mark.parametrize(
    ("inputs", "status", "marked"),
    [
        ([s("a")], "BadArgumentsMissing", None),
        ([s("a"), u32(1), u32(2)], "BadTooManyArguments", None),
        ([s("a"), ua.Variant(1, ua.VariantType.Int64)], "BadTypeMismatch", [True, False]),
        ([u32(1), s("x")], "BadTypeMismatch", [False, False]),
        ([ua.Variant(["a"], ua.VariantType.String, is_array=True), u32(1)], "BadTypeMismatch", [False, True]),
    ],
)
def test_wrong_calls_are_refused_before_the_handler(
    inputs: list[ua.Variant], status: str, marked: list[bool] | None
) -> None:
    values, refused = check_inputs(METHOD, inputs)
    assert values is None and refused is not None
    assert refused.StatusCode == ua.StatusCode(getattr(ua.StatusCodes, status))
    if marked is not None:
        assert [r.is_good() for r in refused.InputArgumentResults] == marked


def test_right_arguments_become_python_values() -> None:
    values, refused = check_inputs(METHOD, [s("a"), u32(3)])
    assert refused is None and values == ["a", 3]


async def test_a_call_reaches_the_handler_with_the_caller_and_encodes_outputs(tree: VariableTree) -> None:
    calls.clear()
    result = await call_result(tree.machines["m1"], METHOD, [s("part"), u32(2)], "anna")
    assert result.StatusCode.is_good()
    assert calls == [("anna", ["part", 2])]
    [out] = result.OutputArguments
    assert out.VariantType == ua.VariantType.String and out.Value == ["part.nc", "b.nc"]


async def test_a_refusal_becomes_its_status_code_and_a_bad_output_an_internal_error(
    tree: VariableTree,
) -> None:
    machine = tree.machines["m1"]
    refused = await call_result(machine, METHOD, [s("busy"), u32(1)], None)
    assert refused.StatusCode == ua.StatusCode(ua.StatusCodes.BadInvalidState)
    odd = await call_result(machine, METHOD, [s("odd"), u32(1)], None)
    assert odd.StatusCode == ua.StatusCode(ua.StatusCodes.BadInternalError)


def test_outputs_must_match_their_declaration() -> None:
    with pytest.raises(ValueError):
        encode_outputs(METHOD, [["a"], "extra"])
