"""Who may do what: ordered roles, and the one check every write, call and acknowledgement passes.

Roles are ranked (viewer < operator < engineer < admin by default; the gateway
file may insert its own). A variable, command or operation names the lowest role
that may use it; a caller's role comes from its sink (the OPC UA session's user,
the MQTT writers' role of the machine, ...) through `WriteContext.role`.

While access control is off (the default, and what a mapping run on its own
gets), every caller may do what the mapping allows, as before.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field

from gateway.errors import AccessDenied

DEFAULT_ROLES: tuple[str, ...] = ("viewer", "operator", "engineer", "admin")


@dataclass
class AccessPolicy:
    roles: tuple[str, ...] = DEFAULT_ROLES
    enabled: bool = False
    _rank: dict[str, int] = field(init=False, repr=False)

    def __post_init__(self) -> None:
        self._rank = {name: index for index, name in enumerate(self.roles)}

    def configure(self, roles: Sequence[str], *, enabled: bool) -> None:
        self.roles = tuple(roles)
        self.enabled = enabled
        self.__post_init__()

    def rank(self, role: str | None) -> int:
        """-1 for no role (or an unknown one): below every role."""
        return -1 if role is None else self._rank.get(role, -1)

    def allows(self, role: str | None, required: str | None) -> bool:
        if not self.enabled or required is None:
            return True
        return self.rank(role) >= self.rank(required)

    def require(self, role: str | None, required: str | None, what: str) -> None:
        """Raise AccessDenied (BadUserAccessDenied) unless `role` may do `what`."""
        if not self.allows(role, required):
            who = f"role {role!r}" if role else "an anonymous caller"
            raise AccessDenied(f"{who} may not {what}: it needs {required!r} or higher")
