"""Who may do what: ordered roles, and the one check every write, call and acknowledgement passes.

Roles are ranked (viewer < operator < engineer < admin by default; the gateway
file may insert its own). A variable, command or operation names the lowest role
that may use it; a caller's role comes from its sink (the OPC UA session's user,
the MQTT writers' role of the machine, ...) through `WriteContext.role`.

Roles are checked with or without users (gateway/app.py configures the
policy): anonymous OPC UA clients act with `access.anonymous`, viewer by
default. Only `access.enabled: false` turns the checks off (`enabled`), and
a policy nobody configured (unit tests of the tree) checks nothing.

The gateway's own writers have no login: the job queue's auto-start (origin
"jobs") and COPYDATA replies ("copydata") act with the role configured for
their origin (`origin_roles`) when their context names none. MQTT requests act
with their machine's MQTT writers' role (`mqtt_role`).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field

from gateway.errors import AccessDenied
from gateway.model.context import WriteContext

DEFAULT_ROLES: tuple[str, ...] = ("viewer", "operator", "engineer", "admin")


@dataclass
class AccessPolicy:
    roles: tuple[str, ...] = DEFAULT_ROLES
    enabled: bool = False
    default_write_role: str | None = None  # for variables whose mapping names no role
    origin_roles: dict[str, str] = field(default_factory=dict)  # {"jobs": "operator", ...}
    mqtt_roles: dict[str, str | None] = field(default_factory=dict)  # per machine
    _rank: dict[str, int] = field(init=False, repr=False)

    def __post_init__(self) -> None:
        self._rank = {name: index for index, name in enumerate(self.roles)}

    def configure(
        self,
        roles: Sequence[str],
        *,
        enabled: bool,
        default_write_role: str | None = None,
        origin_roles: Mapping[str, str | None] | None = None,
        mqtt_roles: Mapping[str, str | None] | None = None,
    ) -> None:
        self.roles = tuple(roles)
        self.enabled = enabled
        self.default_write_role = default_write_role
        self.origin_roles = {k: v for k, v in (origin_roles or {}).items() if v is not None}
        self.mqtt_roles = dict(mqtt_roles or {})
        self.__post_init__()

    def role_of(self, ctx: WriteContext) -> str | None:
        """The role a caller acts with: its own, else its origin's (see the module docstring)."""
        role = ctx.role
        return role if role is not None else self.origin_roles.get(ctx.origin)

    def mqtt_role(self, machine: str) -> str | None:
        """The role of MQTT /set and command requests for `machine` (None: no role, refused while enabled)."""
        return self.mqtt_roles.get(machine)

    def rank(self, role: str | None) -> int:
        """-1 for no role (or an unknown one): below every role."""
        return -1 if role is None else self._rank.get(role, -1)

    def allows(self, role: str | None, required: str | None) -> bool:
        if not self.enabled or required is None:
            return True
        needed = self._rank.get(required)
        if needed is None:  # a role the configuration does not define: nobody has it (fail closed)
            return False
        return self.rank(role) >= needed

    def require(self, role: str | None, required: str | None, what: str) -> None:
        """Raise AccessDenied (BadUserAccessDenied) unless `role` may do `what`."""
        if not self.allows(role, required):
            who = f"role {role!r}" if role else "an anonymous caller"
            raise AccessDenied(f"{who} may not {what}: it needs {required!r} or higher")
