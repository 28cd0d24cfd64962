"""Users, roles and access control (gateway file): who may log in, and what each role may do.

```yaml
roles: [viewer, operator, engineer, admin]      # lowest first; insert your own
users:
  - {name: olga, password_hash: "scrypt$…", role: operator}   # cnc-gateway hash-password
access:
  enabled: auto              # logins as soon as users are configured; false: no role is checked at all
  anonymous: viewer          # the role of OPC UA clients without credentials, users or not; or refuse
  default_write_role: operator
  mqtt_writer_role: null     # role of MQTT /set and command requests (a machine's mqtt.writer_role overrides)
  copydata_role: null        # role of COPYDATA accept_writes
  jobs_role: operator        # role of the job queue's auto-start writes
```

Roles are checked with or without users, so anonymous OPC UA clients only read
unless the gateway file gives them a role that may write (`anonymous: operator`),
or turns the checks off (`enabled: false`); the gateway warns at start-up about
what that opens. Without users (and `enabled: auto`), the doors a mapping opens
itself (`mqtt.writable`/`commands`, COPYDATA `accept_writes`, the jobs' auto-start)
act with their role, or with the highest role when none is set (`door_role`).

Role names are checked here against `roles`; the mapping files' roles are
checked against them by the loader.
"""

from __future__ import annotations

import re
from collections.abc import Sequence
from typing import Literal

from pydantic import Field, field_validator

from gateway.auth.passwords import parse_hash
from gateway.model.access import DEFAULT_ROLES
from gateway.settings.base import Strict

ROLE_RE = re.compile(r"^[a-z][a-z0-9_\-]{0,31}$")
USER_RE = re.compile(r"^[A-Za-z0-9_][A-Za-z0-9_.@\-]{0,63}$")
REFUSE = "refuse"


def check_role_name(name: str) -> str:
    """The syntax of a role name (whether it exists is checked against the gateway file's roles)."""
    if not isinstance(name, str) or not ROLE_RE.match(name):
        raise ValueError(
            f"role {name!r} must be 1-32 lower-case letters, digits, '-' or '_', starting with a letter"
        )
    if name == REFUSE:
        raise ValueError(f"{REFUSE!r} is not a role name (it is the value that refuses anonymous logins)")
    return name


def unknown_role(name: str, roles: Sequence[str]) -> str | None:
    """The message for a role that `roles` does not define, or None when it does."""
    if name in roles:
        return None
    return f"{name!r} is not a role; the roles are {', '.join(roles)} (gateway file: roles)"


class UserConfig(Strict):
    """One login for the gateway's OPC UA server. Passwords are stored as scrypt hashes only."""

    name: str = Field(description="Login name")
    password_hash: str = Field(description="scrypt hash from `cnc-gateway hash-password`, never the password")
    role: str = Field(description="One of the gateway file's roles")

    @field_validator("name")
    @classmethod
    def _name(cls, name: str) -> str:
        if not USER_RE.match(name):
            raise ValueError(f"user name {name!r} must be 1-64 letters, digits, '_', '.', '@' or '-'")
        if name.lower() == "anonymous":
            raise ValueError("'anonymous' is not a user; use access.anonymous for logins without credentials")
        return name

    @field_validator("password_hash")
    @classmethod
    def _hash(cls, value: str) -> str:
        parse_hash(value)
        return value

    @field_validator("role")
    @classmethod
    def _role(cls, role: str) -> str:
        return check_role_name(role)


class LoginLockout(Strict):
    """Repeated wrong passwords from one address: after `failures` within `window` seconds,
    that address's logins are refused, unchecked, for `duration` seconds. One count per address
    for every door that checks passwords: OPC UA, the web console and REST API, the FTP inbox."""

    failures: int = Field(default=5, ge=1, le=1000)
    window: float = Field(default=60.0, gt=0, description="Seconds")
    duration: float = Field(default=300.0, gt=0, description="Seconds")


class AccessConfig(Strict):
    """Whether roles are enforced, and the roles of callers that have no login of their own."""

    enabled: bool | Literal["auto"] = Field(
        default="auto",
        description="auto: logins and every role as soon as users are configured (without users, anonymous "
        "clients still get the anonymous role, and MQTT/COPYDATA writes the mapping opens act with the "
        "highest role unless their role is set); true: as with users; false: no role is checked, anonymous "
        "OPC UA clients may write whatever the mapping allows (warned at start-up)",
    )
    anonymous: str = Field(
        default="viewer",
        description="Role of OPC UA clients without credentials, with or without users, or 'refuse'. "
        "viewer reads only; a role that may write opens those writes to anyone who reaches the endpoint "
        "(warned at start-up)",
    )
    default_write_role: str = Field(
        default="operator", description="Role needed to write a variable whose mapping names none"
    )
    mqtt_writer_role: str | None = Field(
        default=None,
        description="Role of MQTT /set and command requests; a machine's mqtt.writer_role overrides it. "
        "None: refused while access control is on",
    )
    copydata_role: str | None = Field(
        default=None, description="Role of writes from COPYDATA replies (accept_writes); None: refused"
    )
    jobs_role: str | None = Field(
        default="operator", description="Role of the job queue's auto-start writes (select, start)"
    )
    lockout: LoginLockout = Field(
        default_factory=LoginLockout,
        description="Failed logins per address, counted across every door (OPC UA, web, FTP inbox): "
        "after `failures` within `window` s, every login from that address is refused for `duration` s",
    )
    audit_retention: int = Field(
        default=365, ge=0, description="Days the audit table keeps its entries; 0 keeps them for ever"
    )

    @field_validator("anonymous")
    @classmethod
    def _anonymous(cls, value: str) -> str:
        return value if value == REFUSE else check_role_name(value)

    @field_validator("default_write_role", "mqtt_writer_role", "copydata_role", "jobs_role")
    @classmethod
    def _roles(cls, value: str | None) -> str | None:
        return None if value is None else check_role_name(value)

    def is_enabled(self, users: Sequence[UserConfig]) -> bool:
        """Whether logins govern access: users are configured, or `enabled: true`."""
        return bool(users) if self.enabled == "auto" else bool(self.enabled)

    def checks_roles(self) -> bool:
        """Whether roles are checked at all: always, unless `enabled: false` turns them off."""
        return self.enabled is not False

    def door_role(self, role: str | None, users: Sequence[UserConfig], roles: Sequence[str]) -> str | None:
        """The role of a door nobody logs in at (MQTT writers, COPYDATA replies, the jobs' auto-start):
        its own; without one, while logins do not govern access, the highest (the mapping's own switch
        opened that door); else none, and the door is refused."""
        if role is not None or self.is_enabled(users) or not roles:
            return role
        return roles[-1]


def check_roles(roles: list[str]) -> list[str]:
    for name in roles:
        check_role_name(name)
    seen = set()
    for name in roles:
        if name in seen:
            raise ValueError(f"role {name!r} is listed twice")
        seen.add(name)
    return roles


def check_users(users: list[UserConfig], roles: Sequence[str]) -> list[UserConfig]:
    seen: set[str] = set()
    for index, user in enumerate(users):
        if user.name in seen:
            raise ValueError(f"users[{index}]: user {user.name!r} is listed twice")
        seen.add(user.name)
        problem = unknown_role(user.role, roles)
        if problem:
            raise ValueError(f"users[{index}] ({user.name}): {problem}")
    return users


def check_access(access: AccessConfig, roles: Sequence[str], users: Sequence[UserConfig]) -> AccessConfig:
    named = [
        ("anonymous", None if access.anonymous == REFUSE else access.anonymous),
        ("default_write_role", access.default_write_role),
        ("mqtt_writer_role", access.mqtt_writer_role),
        ("copydata_role", access.copydata_role),
        ("jobs_role", access.jobs_role),
    ]
    problems = []
    for key, role in named:
        problem = unknown_role(role, roles) if role is not None else None
        if problem:
            problems.append(f"access.{key}: {problem}")
    if problems:
        raise ValueError("; ".join(problems))
    if access.anonymous == REFUSE and not users:
        raise ValueError("access.anonymous is 'refuse' and no users are configured: nobody could log in")
    return access


__all__ = [
    "DEFAULT_ROLES",
    "AccessConfig",
    "LoginLockout",
    "UserConfig",
    "check_access",
    "check_role_name",
    "check_roles",
    "check_users",
    "unknown_role",
]
