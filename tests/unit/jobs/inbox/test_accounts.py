"""Inbox accounts: secrets from hashes or the environment, and which machines each login may use."""

from __future__ import annotations

import pytest

from gateway.auth.passwords import hash_password
from gateway.config.jobs import InboxConfig
from gateway.errors import ConfigError
from gateway.jobs.inbox.accounts import Accounts

HASH = hash_password("pw", n=2**10)
SERVED = ["laser", "plasma"]


def accounts(environ: dict[str, str] | None = None, **inbox: object) -> Accounts:
    return Accounts.from_config(InboxConfig.model_validate(inbox), SERVED, environ or {})


def test_hashed_and_environment_passwords_both_work() -> None:
    acc = accounts(
        {"OPS_PW": "from-env"},
        accounts=[
            {"user": "nest", "password_hash": HASH},
            {"user": "ops", "password_env": "OPS_PW", "machines": ["plasma"]},
        ],
    )
    assert acc.authenticate("nest", "pw").machines == {"laser", "plasma"}
    assert acc.authenticate("ops", "from-env").machines == {"plasma"}
    assert acc.authenticate("nest", "wrong") is None
    assert acc.authenticate("ops", "pw") is None
    assert acc.authenticate("nobody", "pw") is None


def test_machines_not_served_are_not_offered() -> None:
    acc = accounts(accounts=[{"user": "nest", "password_hash": HASH, "machines": ["laser", "press"]}])
    assert acc.authenticate("nest", "pw").machines == {"laser"}


def test_a_missing_environment_password_is_a_configuration_error() -> None:
    with pytest.raises(ConfigError, match="NEST_PW"):
        accounts(accounts=[{"user": "nest", "password_env": "NEST_PW"}])


def test_anonymous_is_off_unless_enabled() -> None:
    assert accounts(accounts=[{"user": "nest", "password_hash": HASH}]).authenticate("anonymous", "x") is None
    acc = accounts(anonymous=True, anonymous_machines=["plasma"])
    assert acc.anonymous_allowed and len(acc) == 1
    for login in ("anonymous", "ftp", "Anonymous"):
        assert acc.authenticate(login, "me@example.com").machines == {"plasma"}
