"""Roles in the tree's one write path and in every method call, and the audit entry each one leaves."""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import Any

import pytest

from gateway.config.loader import load_mapping
from gateway.errors import AccessDenied, InvalidState, NotWritable, OutOfRange, TypeMismatch
from gateway.model.audit import AuditEntry
from gateway.model.context import WriteContext
from gateway.model.methods import Argument, Method
from gateway.model.tree import Machine, VariableNode, VariableTree
from gateway.model.types import TypeSpec

MAPPING = """
machine: m1
driver: {endpoint: "opc.tcp://127.0.0.1:4841"}
defaults: {write_role: engineer}
variables:
  - {path: Feed/Override, source: "ns=2;s=o", type: UInt16, access: readwrite, role: operator,
     range: {min: 0, max: 150}}
  - {path: Process/Gas, source: "ns=2;s=g", type: Double, access: readwrite}
  - {path: Feed/Rate, source: "ns=2;s=r", type: Double}
"""


class Writer:
    def __init__(self) -> None:
        self.writes: list[tuple[str, Any]] = []

    async def write(self, node: VariableNode, raw: Any) -> None:
        self.writes.append((node.path, raw))


async def start(ctx: WriteContext, args: Sequence[Any]) -> Sequence[Any]:
    if args[0] == "alarm":
        raise InvalidState("the machine is in Alarm")
    return [f"started {args[0]}"]


START = Method(
    "Commands",
    "Start",
    "Start",
    (Argument("Program", TypeSpec.parse("String")),),
    (Argument("Result", TypeSpec.parse("String")),),
    start,
    role="operator",
)


@pytest.fixture
def machine(tmp_path: Path) -> Machine:
    path = tmp_path / "m1.yaml"
    path.write_text(MAPPING)
    tree = VariableTree([load_mapping(path).definition()])
    tree.access.configure(
        ["viewer", "operator", "engineer", "admin"],
        enabled=True,
        default_write_role="operator",
        origin_roles={"jobs": "operator", "copydata": None},
    )
    m = tree.machines["m1"]
    m.writer = Writer()
    m.add_method(START)
    return m


def entries(machine: Machine) -> list[AuditEntry]:
    got: list[AuditEntry] = []
    machine.tree.audit_sinks.append(got.append)
    return got


async def test_a_write_needs_the_variables_role_and_leaves_an_entry_either_way(machine: Machine) -> None:
    audit = entries(machine)
    override = machine.nodes["Feed/Override"]
    with pytest.raises(
        AccessDenied, match="role 'viewer' may not write m1/Feed/Override: it needs 'operator'"
    ):
        await machine.write_node(override, 50, WriteContext("opcua", "vera", "viewer"))
    await machine.write_node(override, 50, WriteContext("opcua", "otto", "operator"))
    assert machine.writer.writes == [("Feed/Override", 50)]  # type: ignore[union-attr]
    refused, done = audit
    assert (refused.user, refused.role, refused.status, refused.target, refused.new) == (
        "vera",
        "viewer",
        "BadUserAccessDenied",
        "Feed/Override",
        "50",
    )
    assert (done.status, done.reason, done.old, done.origin, done.kind) == ("Good", "", "0", "opcua", "write")


async def test_the_machine_default_applies_to_variables_without_a_role(machine: Machine) -> None:
    gas = machine.nodes["Process/Gas"]
    assert (
        machine.write_role(gas) == "engineer"
        and machine.write_role(machine.nodes["Feed/Override"]) == "operator"
    )
    with pytest.raises(AccessDenied):
        await machine.write_node(gas, 1.5, WriteContext("opcua", "otto", "operator"))
    await machine.write_node(gas, 1.5, WriteContext("opcua", "erik", "engineer"))


async def test_refusals_of_every_kind_are_audited(machine: Machine) -> None:
    audit = entries(machine)
    ctx = WriteContext("mqtt", role="admin")
    for node, value, error in [
        ("Feed/Rate", 1.0, NotWritable),
        ("Feed/Override", "50", TypeMismatch),
        ("Feed/Override", 151, OutOfRange),
    ]:
        with pytest.raises(error):
            await machine.write_node(machine.nodes[node], value, ctx)
    assert [e.status for e in audit] == ["BadNotWritable", "BadTypeMismatch", "BadOutOfRange"]


async def test_a_sinks_own_check_runs_after_the_role_check_inside_the_audit(machine: Machine) -> None:
    audit = entries(machine)
    checked: list[bool] = []

    def check() -> None:
        checked.append(True)
        raise TypeMismatch("wrong Variant")

    with pytest.raises(AccessDenied):
        await machine.write_node(
            machine.nodes["Feed/Override"], 5, WriteContext("opcua", role="viewer"), check=check
        )
    assert not checked  # a viewer hears "access denied" whatever it sent
    with pytest.raises(TypeMismatch):
        await machine.write_node(
            machine.nodes["Feed/Override"], 5, WriteContext("opcua", role="operator"), check=check
        )
    assert [e.status for e in audit] == ["BadUserAccessDenied", "BadTypeMismatch"]


async def test_gateway_writers_act_with_their_origins_role(machine: Machine) -> None:
    await machine.write_node(machine.nodes["Feed/Override"], 60, WriteContext("jobs", "nesting"))
    with pytest.raises(AccessDenied, match="an anonymous caller"):  # copydata: no role configured
        await machine.write_node(machine.nodes["Feed/Override"], 60, WriteContext("copydata"))


async def test_method_calls_are_authorised_and_audited(machine: Machine) -> None:
    audit = entries(machine)
    with pytest.raises(AccessDenied, match=r"may not call m1/Commands\.Start"):
        await machine.call_method(START, ["a.nc"], WriteContext("opcua", "vera", "viewer"))
    assert await machine.call_method(START, ["a.nc"], WriteContext("mqtt", None, "operator")) == [
        "started a.nc"
    ]
    with pytest.raises(InvalidState):
        await machine.call_method(START, ["alarm"], WriteContext("opcua", "otto", "operator"))
    assert [(e.kind, e.target, e.status, e.new) for e in audit] == [
        ("call", "Commands.Start", "BadUserAccessDenied", '["a.nc"]'),
        ("call", "Commands.Start", "Good", '["a.nc"]'),
        ("call", "Commands.Start", "BadInvalidState", '["alarm"]'),
    ]
    assert audit[2].reason == "the machine is in Alarm"


async def test_with_access_control_off_everyone_may_as_before(machine: Machine) -> None:
    machine.tree.access.configure(machine.tree.access.roles, enabled=False)
    await machine.write_node(machine.nodes["Process/Gas"], 2.0, WriteContext("opcua"))
    assert await machine.call_method(START, ["b.nc"], WriteContext("opcua")) == ["started b.nc"]
