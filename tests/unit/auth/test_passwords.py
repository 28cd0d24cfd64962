"""scrypt password hashes: what the gateway file stores instead of passwords."""

from __future__ import annotations

import pytest

from gateway.auth.passwords import hash_password, parse_hash, verify_password

FAST = {"n": 2**10}  # the default cost is for real accounts; tests need not pay it


def test_a_hash_verifies_its_password_and_nothing_else() -> None:
    encoded = hash_password("s3cret", **FAST)
    assert encoded.startswith("scrypt$1024$8$1$")
    assert verify_password("s3cret", encoded)
    assert not verify_password("s3cret ", encoded)
    assert not verify_password("", encoded)


def test_each_hash_has_its_own_salt() -> None:
    assert hash_password("same", **FAST) != hash_password("same", **FAST)


def test_the_default_cost_is_what_parse_reports() -> None:
    n, r, p, salt, key = parse_hash(hash_password("x"))
    assert (n, r, p) == (2**14, 8, 1) and len(salt) == 16 and len(key) == 32


@pytest.mark.parametrize(
    "encoded",
    [
        "",
        "plain-password",
        "bcrypt$x",
        "scrypt$1000$8$1$AAAAAAAAAAA=$AAAAAAAAAAAAAAAAAAAAAA==",
        "scrypt$1024$8$1$!!!$AAAA",
        "scrypt$1024$8$1$AAAA$AAAA",
        "scrypt$2097152$8$1$AAAAAAAAAAA=$AAAAAAAAAAAAAAAAAAAAAA==",
    ],
)
def test_malformed_hashes_are_errors_to_parse_and_never_match(encoded: str) -> None:
    with pytest.raises(ValueError):
        parse_hash(encoded)
    assert not verify_password("anything", encoded)


def test_an_empty_password_cannot_be_hashed() -> None:
    with pytest.raises(ValueError):
        hash_password("")
