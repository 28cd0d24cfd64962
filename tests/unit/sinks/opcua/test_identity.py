"""What a session's role lets it see: UserAccessLevel per variable, UserExecutable per method; and logins."""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import Any

import pytest
from asyncua import ua
from asyncua.crypto.permission_rules import UserRole

from gateway.auth.passwords import hash_password
from gateway.auth.users import UserDirectory
from gateway.config.loader import load_mapping
from gateway.model.context import WriteContext
from gateway.model.methods import Method
from gateway.model.tree import Machine, VariableTree
from gateway.sinks.opcua.identity import (
    CLIENT_ADDRESS,
    GatewayUserManager,
    address_of,
    session_role,
    user_access_level,
    user_executable,
)

MAPPING = """
machine: m1
driver: {endpoint: "opc.tcp://127.0.0.1:4841"}
variables:
  - {path: Feed/Override, source: "ns=2;s=o", type: UInt16, access: readwrite, role: operator}
  - {path: Machine/Mode, source: "ns=2;s=m", type: Int16, access: readwrite, role: engineer}
  - {path: Feed/Rate, source: "ns=2;s=r", type: Double}
"""
READ = ua.AccessLevel.CurrentRead.mask
READ_WRITE = READ | ua.AccessLevel.CurrentWrite.mask


async def nothing(ctx: WriteContext, args: Sequence[Any]) -> Sequence[Any]:
    return []


@pytest.fixture
def machine(tmp_path: Path) -> Machine:
    path = tmp_path / "m1.yaml"
    path.write_text(MAPPING)
    tree = VariableTree([load_mapping(path).definition()])
    tree.access.configure(
        ["viewer", "operator", "engineer", "admin"], enabled=True, default_write_role="operator"
    )
    return tree.machines["m1"]


@pytest.mark.parametrize(
    ("role", "override", "mode"),
    [
        (None, READ, READ),
        ("viewer", READ, READ),
        ("operator", READ_WRITE, READ),
        ("engineer", READ_WRITE, READ_WRITE),
        ("admin", READ_WRITE, READ_WRITE),
    ],
)
def test_user_access_level_per_role(machine: Machine, role: str | None, override: int, mode: int) -> None:
    policy = machine.tree.access
    assert user_access_level(machine.nodes["Feed/Override"], role, policy) == override
    assert user_access_level(machine.nodes["Machine/Mode"], role, policy) == mode
    assert user_access_level(machine.nodes["Feed/Rate"], "admin", policy) == READ  # read-only stays read-only


def test_with_access_control_off_the_user_access_level_is_the_access_level(machine: Machine) -> None:
    machine.tree.access.configure(machine.tree.access.roles, enabled=False)
    assert user_access_level(machine.nodes["Machine/Mode"], None, machine.tree.access) == READ_WRITE


def test_user_executable_follows_the_methods_role(machine: Machine) -> None:
    policy = machine.tree.access
    delete = Method("Programs", "Delete", "", (), (), nothing, role="operator")
    listing = Method("Programs", "List", "", (), (), nothing)
    assert not user_executable(delete, "viewer", policy) and user_executable(delete, "operator", policy)
    assert user_executable(listing, "viewer", policy) and user_executable(listing, None, policy)


def test_the_user_manager_gives_sessions_their_gateway_role() -> None:
    users = UserDirectory({"otto": (hash_password("pw", n=2**8), "operator")}, anonymous_role="viewer")
    manager = GatewayUserManager(users)
    token = CLIENT_ADDRESS.set("10.0.0.9")
    try:
        otto = manager.get_user(None, username="otto", password="pw")
        anonymous = manager.get_user(None)
        assert manager.get_user(None, username="otto", password="nope") is None
    finally:
        CLIENT_ADDRESS.reset(token)
    assert otto is not None and otto.name == "otto" and session_role(otto) == "operator"
    assert otto.role == UserRole.User  # never asyncua's Admin, which would bypass its own checks
    assert anonymous is not None and anonymous.name is None and session_role(anonymous) == "viewer"
    assert users.limiter.recent_failures("10.0.0.9") == 1


def test_the_address_is_the_host_without_the_port() -> None:
    assert address_of(("10.0.0.9", 50123)) == "10.0.0.9"
    assert address_of(("::1", 4840, 0, 0)) == "::1"
    assert address_of(None) == "unknown"
