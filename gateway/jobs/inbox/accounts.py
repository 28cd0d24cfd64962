"""Who may log in to the inbox, and which machines' folders each login may write to.

Built once from the gateway file's `inbox:` section. A password comes either
from a scrypt hash in the file or from an environment variable named there;
both are checked in constant time, and an unknown user costs as much as a
known one, so timing does not tell which user names exist.
"""

from __future__ import annotations

import hmac
import os
from collections.abc import Collection, Mapping
from dataclasses import dataclass
from functools import cache

from gateway.auth.passwords import hash_password, verify_password
from gateway.config.jobs import ANONYMOUS_USERS, InboxConfig, machines_allowed
from gateway.errors import ConfigError, ConfigIssue


@cache
def _dummy_hash() -> str:
    """Checked against when the user is unknown, so that the answer takes as long as for a real one."""
    return hash_password("not a password", salt=b"cnc-gateway-dummy")


@dataclass(frozen=True, slots=True)
class Account:
    user: str
    machines: frozenset[str]  # the machines this login may use (already intersected with the served ones)
    # Machines this login could use that another shard serves, on a queue that cannot take their jobs here
    # (SQLite): named in the refusal, so that the sender knows where to go.
    elsewhere: frozenset[str] = frozenset()
    password_hash: str | None = None
    password: str | None = None  # from the environment
    anonymous: bool = False

    def check(self, password: str) -> bool:
        """Blocking (scrypt): call it in a worker thread."""
        if self.anonymous:
            return True
        if self.password_hash is not None:
            return verify_password(password, self.password_hash)
        assert self.password is not None
        return hmac.compare_digest(password.encode("utf-8"), self.password.encode("utf-8"))


class Accounts:
    """The inbox's logins. `lookup` never says whether a user exists; `authenticate` does the work."""

    def __init__(self, accounts: Mapping[str, Account], anonymous: Account | None = None) -> None:
        self._accounts = dict(accounts)
        self._anonymous = anonymous

    @classmethod
    def from_config(
        cls,
        config: InboxConfig,
        machines: Collection[str],
        environ: Mapping[str, str] | None = None,
        *,
        elsewhere: Collection[str] = (),
    ) -> Accounts:
        """`machines` are those with a jobs section the inbox takes jobs for; `elsewhere`, those another
        shard serves that it does not. ConfigError if a password_env is not set."""
        env = os.environ if environ is None else environ
        served = sorted(machines)
        others = sorted(set(elsewhere) - set(machines))
        out: dict[str, Account] = {}
        issues: list[ConfigIssue] = []
        for index, acc in enumerate(config.accounts):
            allowed = frozenset(m for m in served if machines_allowed(acc.machines, m))
            password = None
            if acc.password_env is not None:
                password = env.get(acc.password_env)
                if not password:
                    issues.append(
                        ConfigIssue(
                            "<gateway file>",
                            None,
                            f"inbox.accounts[{index}].password_env",
                            f"environment variable {acc.password_env} (password of {acc.user!r}) is not set",
                        )
                    )
                    continue
            refused = frozenset(m for m in others if machines_allowed(acc.machines, m))
            out[acc.user] = Account(acc.user, allowed, refused, acc.password_hash, password)
        if issues:
            raise ConfigError(issues)
        anonymous = None
        if config.anonymous:
            allowed = frozenset(m for m in served if machines_allowed(config.anonymous_machines, m))
            refused = frozenset(m for m in others if machines_allowed(config.anonymous_machines, m))
            anonymous = Account("anonymous", allowed, refused, anonymous=True)
        return cls(out, anonymous)

    def __len__(self) -> int:
        return len(self._accounts) + (1 if self._anonymous else 0)

    @property
    def anonymous_allowed(self) -> bool:
        return self._anonymous is not None

    def lookup(self, user: str) -> Account | None:
        if user.lower() in ANONYMOUS_USERS:
            return self._anonymous
        return self._accounts.get(user)

    def authenticate(self, user: str, password: str) -> Account | None:
        """The account if the password is right. Blocking (scrypt): call it in a worker thread."""
        account = self.lookup(user)
        if account is None:
            verify_password(password, _dummy_hash())
            return None
        return account if account.check(password) else None
