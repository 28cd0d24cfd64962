from __future__ import annotations

import logging

import pytest

from gateway.auth.passwords import hash_password
from gateway.auth.ratelimit import LoginLimiter
from gateway.auth.users import Identity, UserDirectory
from gateway.config.gateway import GatewayConfig


@pytest.fixture(scope="module")
def hashed() -> str:
    return hash_password("s3cret", n=2**8)


def directory(hashed: str, **kwargs: object) -> UserDirectory:
    return UserDirectory({"olga": (hashed, "operator")}, anonymous_role="viewer", **kwargs)  # type: ignore[arg-type]


def test_the_right_password_gives_the_users_role(hashed: str) -> None:
    assert directory(hashed).authenticate("olga", "s3cret", "10.0.0.5") == Identity("olga", "operator")


def test_wrong_passwords_and_unknown_users_are_refused_and_logged_without_the_password(
    hashed: str, caplog: pytest.LogCaptureFixture
) -> None:
    caplog.set_level(logging.INFO, logger="gateway.auth")
    users = directory(hashed)
    assert users.authenticate("olga", "guess1", "10.0.0.5") is None
    assert users.authenticate("mallory", "guess2", "10.0.0.5") is None
    assert "refused (wrong password)" in caplog.text and "refused (unknown user)" in caplog.text
    assert "guess" not in caplog.text


def test_a_locked_out_address_is_refused_even_with_the_right_password(hashed: str) -> None:
    users = directory(hashed, limiter=LoginLimiter(failures=2, window=60, lockout=300))
    users.authenticate("olga", "x", "10.0.0.5")
    users.authenticate("olga", "y", "10.0.0.5")
    assert users.authenticate("olga", "s3cret", "10.0.0.5") is None
    assert users.authenticate("olga", "s3cret", "10.0.0.6") == Identity("olga", "operator")


def test_anonymous_gets_the_configured_role_or_is_refused(hashed: str) -> None:
    assert directory(hashed).anonymous("10.0.0.5") == Identity(None, "viewer")
    refusing = UserDirectory({}, anonymous_role=None, anonymous_allowed=False)
    assert refusing.anonymous("10.0.0.5") is None


def test_built_from_the_gateway_file(hashed: str) -> None:
    config = GatewayConfig.model_validate(
        {
            "users": [{"name": "olga", "password_hash": hashed, "role": "engineer"}],
            "access": {"anonymous": "refuse", "lockout": {"failures": 2, "window": 10, "duration": 20}},
        }
    )
    users = config.user_directory()
    assert users.has_users and not users.anonymous_allowed
    assert users.limiter.failures == 2 and users.limiter.lockout == 20
    assert users.authenticate("olga", "s3cret", "h") == Identity("olga", "engineer")
