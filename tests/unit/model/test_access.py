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
