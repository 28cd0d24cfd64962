from __future__ import annotations

from pathlib import Path
from typing import Any

import pytest
from asyncua import ua

from gateway.config.loader import load_mapping
from gateway.errors import ControllerRefused, ControllerUnavailable
from gateway.model.context import WriteContext
from gateway.model.tree import VariableNode, VariableTree
from gateway.sinks.opcua.values import value_kind
from gateway.sinks.opcua.writes import precheck, write_node

MAPPING = """
machine: m1
driver: {endpoint: "opc.tcp://127.0.0.1:4841"}
variables:
  - {path: Target, source: "ns=2;s=t", type: Double, source_type: Int32, scale: {gain: 0.01},
     access: readwrite, range: {min: 0, max: 100}}
  - {path: Position, source: "ns=2;s=p", type: Double}
  - {path: Table, source: "ns=2;s=tb", type: "Int32[]", access: readwrite}
"""


class Recorder:
    def __init__(self, error: Exception | None = None) -> None:
        self.writes: list[tuple[str, Any]] = []
        self.error = error

    async def write(self, node: VariableNode, raw: Any) -> None:
        if self.error is not None:
            raise self.error
        self.writes.append((node.path, raw))


@pytest.fixture
def tree(tmp_path: Path) -> VariableTree:
    path = tmp_path / "m1.yaml"
    path.write_text(MAPPING)
    return VariableTree([load_mapping(path).definition()])


def wv(
    value: Any,
    vtype: ua.VariantType,
    *,
    attr: int = ua.AttributeIds.Value,
    status: int = ua.StatusCodes.Good,
    index_range: str | None = None,
) -> ua.WriteValue:
    dv = ua.DataValue(ua.Variant(value, vtype), ua.StatusCode(status))
    return ua.WriteValue(NodeId=ua.NodeId("x", 2), AttributeId=attr, IndexRange=index_range, Value=dv)


def code(name: str) -> ua.StatusCode:
    return ua.StatusCode(getattr(ua.StatusCodes, name))


def check(tree: VariableTree, path: str, write: ua.WriteValue) -> ua.StatusCode | None:
    node = tree.find("m1", path)
    return precheck(node, value_kind(node.type), write)


def test_a_matching_write_passes(tree: VariableTree) -> None:
    assert check(tree, "Target", wv(5.0, ua.VariantType.Double)) is None
    assert check(tree, "Table", wv([1, 2], ua.VariantType.Int32)) is None


@pytest.mark.parametrize(
    ("path", "write", "expected"),
    [
        ("Position", wv(5.0, ua.VariantType.Double), "BadNotWritable"),  # read-only
        ("Target", wv(5.0, ua.VariantType.Double, attr=ua.AttributeIds.DisplayName), "BadNotWritable"),
        ("Target", wv(5, ua.VariantType.Int32), "BadTypeMismatch"),
        ("Target", wv(5.0, ua.VariantType.Float), "BadTypeMismatch"),
        ("Target", wv([5.0], ua.VariantType.Double), "BadTypeMismatch"),  # array into a scalar
        ("Table", wv(5, ua.VariantType.Int32), "BadTypeMismatch"),  # scalar into an array
        ("Table", wv([1.0], ua.VariantType.Double), "BadTypeMismatch"),
        ("Target", wv(None, ua.VariantType.Null), "BadTypeMismatch"),
        ("Target", wv(5.0, ua.VariantType.Double, status=ua.StatusCodes.BadSensorFailure), "BadTypeMismatch"),
        ("Table", wv([1, 2], ua.VariantType.Int32, index_range="1"), "BadWriteNotSupported"),
    ],
)
def test_strict_checks_refuse_before_the_tree(
    tree: VariableTree, path: str, write: ua.WriteValue, expected: str
) -> None:
    assert check(tree, path, write) == code(expected)


def test_internal_variables_are_not_writable(tree: VariableTree) -> None:
    node = tree.find("m1", "Status/Connected")
    assert precheck(node, value_kind(node.type), wv(True, ua.VariantType.Boolean)) == code("BadNotWritable")


def test_matrix_into_a_one_dimensional_array_is_refused(tree: VariableTree) -> None:
    write = wv([[1, 2], [3, 4]], ua.VariantType.Int32)
    assert write.Value.Value.Dimensions == [2, 2]
    assert check(tree, "Table", write) == code("BadTypeMismatch")


async def test_accepted_write_reaches_the_writer_unscaled_with_the_caller(tree: VariableTree) -> None:
    machine = tree.machines["m1"]
    machine.writer = recorder = Recorder()
    seen: list[WriteContext] = []

    async def hook(node: VariableNode, value: Any, ctx: WriteContext) -> None:
        seen.append(ctx)

    tree.write_hooks.append(hook)
    node = tree.find("m1", "Target")
    status = await write_node(node, value_kind(node.type), wv(12.5, ua.VariantType.Double), "alice")
    assert status == code("Good")
    assert recorder.writes == [("Target", 1250)]
    assert (seen[0].origin, seen[0].user) == ("opcua", "alice")


@pytest.mark.parametrize(
    ("error", "value", "expected"),
    [
        (None, 250.0, "BadOutOfRange"),
        (ControllerRefused("no", status="BadUserAccessDenied"), 1.0, "BadUserAccessDenied"),
        (ControllerRefused("no"), 1.0, "BadWriteNotSupported"),
        (ControllerUnavailable("down"), 1.0, "BadNotConnected"),
        (ControllerRefused("odd", status="NotAStatus"), 1.0, "BadInternalError"),
        (RuntimeError("driver bug"), 1.0, "BadInternalError"),
    ],
)
async def test_refusals_map_to_their_status_codes(
    tree: VariableTree, error: Exception | None, value: float, expected: str
) -> None:
    machine = tree.machines["m1"]
    machine.writer = recorder = Recorder(error)
    node = tree.find("m1", "Target")
    status = await write_node(node, value_kind(node.type), wv(value, ua.VariantType.Double), None)
    assert status == code(expected)
    assert recorder.writes == []


async def test_refused_precheck_never_reaches_the_writer(tree: VariableTree) -> None:
    machine = tree.machines["m1"]
    machine.writer = recorder = Recorder()
    node = tree.find("m1", "Target")
    status = await write_node(node, value_kind(node.type), wv(3, ua.VariantType.Int32), None)
    assert status == code("BadTypeMismatch")
    assert recorder.writes == []
