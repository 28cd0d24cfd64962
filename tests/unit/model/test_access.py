from __future__ import annotations

import pytest

from gateway.errors import AccessDenied
from gateway.model.access import AccessPolicy


def test_off_by_default_everyone_may() -> None:
    policy = AccessPolicy()
    policy.require(None, "admin", "do anything")


def test_ranked_roles() -> None:
    policy = AccessPolicy(enabled=True)
    assert policy.allows("engineer", "operator") and policy.allows("operator", "operator")
    assert not policy.allows("viewer", "operator") and not policy.allows(None, "viewer")
    with pytest.raises(AccessDenied, match="role 'viewer' may not start: it needs 'operator'"):
        policy.require("viewer", "operator", "start")


def test_roles_can_be_extended() -> None:
    policy = AccessPolicy(enabled=True)
    policy.configure(["viewer", "operator", "shift-lead", "engineer", "admin"], enabled=True)
    assert policy.allows("shift-lead", "operator") and not policy.allows("shift-lead", "engineer")
    assert not policy.allows("stranger", "viewer")


def test_a_role_the_configuration_does_not_define_is_nobodys() -> None:
    policy = AccessPolicy(enabled=True)
    assert not policy.allows("admin", "foreman")


def test_gateway_writers_without_a_role_of_their_own_use_their_origins() -> None:
    from gateway.model.context import WriteContext

    policy = AccessPolicy()
    policy.configure(
        ["viewer", "operator"],
        enabled=True,
        origin_roles={"jobs": "operator", "copydata": None},
        mqtt_roles={"m1": "viewer"},
    )
    assert policy.role_of(WriteContext("jobs")) == "operator"
    assert policy.role_of(WriteContext("jobs", role="viewer")) == "viewer"  # a context's own role wins
    assert policy.role_of(WriteContext("copydata")) is None
    assert policy.mqtt_role("m1") == "viewer" and policy.mqtt_role("m2") is None
