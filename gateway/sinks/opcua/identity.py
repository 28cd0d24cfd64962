"""OPC UA sessions and the gateway's users: logins, and what a session may see itself allowed to do.

- `GatewayUserManager` is asyncua's user manager: username/password tokens are
  checked against the gateway's users (gateway/auth/users.py), anonymous ones get
  the configured role or are refused. asyncua turns a refusal into
  BadUserAccessDenied. The client's address reaches it through `CLIENT_ADDRESS`,
  which the server module sets around each ActivateSession.
- `user_access_level` and `user_executable` answer the UserAccessLevel and
  UserExecutable attributes for one session's role, so a viewer's client shows
  Feed/Override as read-only and Programs.Delete as not executable.

asyncua's own user roles stay at `User` for everyone (never `Admin`, which
would bypass its access checks and allow AddNodes/DeleteNodes); the gateway's
role travels beside it in `SessionUser.role_name`.
"""

from __future__ import annotations

import logging
from collections.abc import Sequence
from contextvars import ContextVar
from dataclasses import dataclass
from typing import Any

from asyncua.crypto.permission_rules import User, UserRole
from asyncua.server.user_managers import UserManager

from gateway.auth.users import UserDirectory
from gateway.model.access import AccessPolicy
from gateway.model.methods import Method
from gateway.model.reach import reach
from gateway.model.tree import VariableNode, VariableTree
from gateway.sinks.opcua.address_space import READ, access_level

log = logging.getLogger("gateway.sinks.opcua")

# "host" of the client whose ActivateSession is being served (set by the server module).
CLIENT_ADDRESS: ContextVar[str] = ContextVar("opcua_client_address", default="unknown")


@dataclass
class SessionUser(User):
    """asyncua's User, plus the gateway role the session acts with."""

    role_name: str | None = None


class GatewayUserManager(UserManager):
    """asyncua user manager (`get_user` is called synchronously from ActivateSession)."""

    def __init__(self, directory: UserDirectory) -> None:
        self.directory = directory

    def get_user(
        self, iserver: Any, username: str | None = None, password: str | None = None, certificate: Any = None
    ) -> User | None:
        address = CLIENT_ADDRESS.get()
        if username is None:  # anonymous (certificate identity tokens are not offered)
            identity = self.directory.anonymous(address)
        else:
            identity = self.directory.authenticate(username, password or "", address)
        if identity is None:
            return None
        return SessionUser(role=UserRole.User, name=identity.name, role_name=identity.role)


def session_role(user: Any) -> str | None:
    """The gateway role of a session's user (None: unknown, e.g. a sink built without a user directory)."""
    role = getattr(user, "role_name", None)
    return role if isinstance(role, str) else None


def user_access_level(node: VariableNode, role: str | None, policy: AccessPolicy) -> int:
    """UserAccessLevel of `node` for a session with `role`: CurrentWrite only if that role may write it."""
    level = access_level(node)
    if level == READ:
        return level
    if policy.allows(role, node.machine.write_role(node)):
        return level
    return READ


def user_executable(method: Method, role: str | None, policy: AccessPolicy) -> bool:
    return policy.allows(role, method.role)


def address_of(peer: Any) -> str:
    """The host part of a peer name (host, port[, …]); the port changes with every connection."""
    if isinstance(peer, (tuple, list)) and peer:
        return str(peer[0])
    return str(peer) if peer else "unknown"


def report_anonymous(
    users: UserDirectory | None, tree: VariableTree, endpoint: str, endpoints: Sequence[str]
) -> None:
    """Say at start-up what clients without credentials may change. Nothing, by default (they are
    viewers); a gateway file that gives them more gets a WARNING naming their role, the endpoints and,
    per machine, the writes, calls and alarm acknowledgements that are open to anyone reaching them."""
    if users is not None and not users.anonymous_allowed:
        log.info("OPC UA: anonymous logins are refused (access.anonymous: refuse)")
        return
    role = users.anonymous_role if users is not None else None
    policy = tree.access
    where = f"{endpoint} (every endpoint: {', '.join(endpoints)})"
    open_ = [r for r in (reach(m, role) for m in tree.machines.values()) if r]
    if not open_:
        log.info("OPC UA: anonymous clients on %s act as %s: they read, and change nothing", where, role)
        return
    why = (
        "access.enabled is false: no role is checked"
        if not policy.enabled
        else f"access.anonymous gives them role {role!r}"
    )
    log.warning(
        "OPC UA: anonymous clients, without user name or password, on %s may change machines (%s): %s",
        where,
        why,
        " | ".join(r.describe() for r in open_),
    )
