"""The gateway's users: who may log in (OPC UA), with which role, and what happens to wrong passwords.

Built from plain values: names with their hashes and roles, the anonymous role,
a lockout limiter; the configuration builds one from the gateway file (`users:`,
`access:`; `GatewayConfig.user_directory()`), so that this package needs nothing
of the configuration. Protocol-neutral: the OPC UA sink adapts it to asyncua's
user manager (gateway/sinks/opcua/identity.py).

- A known user with the right password gets its role.
- A wrong password, or an unknown user, is refused; an unknown user costs as
  much scrypt work as a known one, so timing does not tell which names exist.
- After `lockout.failures` refusals from one address within `lockout.window`
  seconds, that address is refused for `lockout.duration` seconds without any
  check (gateway/auth/ratelimit.py). The limiter is the gateway's one, shared
  with every other door that checks passwords (gateway/auth/lockout.py).
- Anonymous logins get `access.anonymous` as their role, or are refused.

Every refusal is logged with the address, never with the password.
"""

from __future__ import annotations

import logging
from collections.abc import Mapping
from dataclasses import dataclass
from functools import cache

from gateway.auth.lockout import locked_out, login_failed
from gateway.auth.passwords import hash_password, verify_password
from gateway.auth.ratelimit import LoginLimiter

log = logging.getLogger("gateway.auth")


@dataclass(frozen=True, slots=True)
class Identity:
    """Who a session is: a user name (None for anonymous) and the role it acts with."""

    name: str | None
    role: str | None


@cache
def _dummy_hash() -> str:
    return hash_password("not a password", salt=b"cnc-gateway-dummy-user")


class UserDirectory:
    def __init__(
        self,
        users: Mapping[str, tuple[str, str]],  # name -> (password hash, role)
        *,
        anonymous_role: str | None,
        anonymous_allowed: bool = True,
        limiter: LoginLimiter | None = None,
    ) -> None:
        self._users = dict(users)
        self.anonymous_role = anonymous_role
        self.anonymous_allowed = anonymous_allowed
        self.limiter = limiter or LoginLimiter()

    @property
    def has_users(self) -> bool:
        return bool(self._users)

    def role_of(self, name: str) -> str | None:
        """The role of a configured user (None: no such user), for credentials other than a password
        (the web console's API tokens), which must follow the user's current role."""
        known = self._users.get(name)
        return None if known is None else known[1]

    def anonymous(self, address: str, via: str = "OPC UA") -> Identity | None:
        if not self.anonymous_allowed:
            log.info("%s: anonymous login from %s refused (access.anonymous: refuse)", via, address)
            return None
        return Identity(None, self.anonymous_role)

    def authenticate(self, name: str, password: str, address: str, via: str = "OPC UA") -> Identity | None:
        """The user's identity, or None (refused). Blocking: one scrypt check (~50 ms) unless locked out."""
        if locked_out(self.limiter, name, address, via):
            return None
        known = self._users.get(name)
        encoded, role = known if known is not None else (_dummy_hash(), None)
        if verify_password(password, encoded) and known is not None:
            log.info("%s: %s logged in from %s as %s", via, name, address, role)
            return Identity(name, role)
        login_failed(
            self.limiter, name, address, via, "wrong password" if known is not None else "unknown user"
        )
        return None
