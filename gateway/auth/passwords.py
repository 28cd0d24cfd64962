"""Password hashes for the gateway's own accounts: scrypt from the standard library.

Config files hold hashes, never passwords. The encoded form carries its own
parameters, so the cost can be raised later without invalidating old hashes:

    scrypt$16384$8$1$<salt, base64>$<key, base64>

`cnc-gateway hash-password` prints one. Verification is constant-time and never
raises for a malformed hash: it is simply not a match.
"""

from __future__ import annotations

import base64
import hashlib
import hmac
import os

SCHEME = "scrypt"
N, R, P = 2**14, 8, 1  # about 16 MiB and a few tens of milliseconds per check
SALT_BYTES = 16
KEY_BYTES = 32
MAX_N = 2**20  # refuse hashes that would cost more than 1 GiB to check


def hash_password(password: str, *, n: int = N, r: int = R, p: int = P, salt: bytes | None = None) -> str:
    """The encoded scrypt hash of `password` with a fresh random salt."""
    if not password:
        raise ValueError("the password must not be empty")
    salt = os.urandom(SALT_BYTES) if salt is None else salt
    key = _derive(password, salt, n, r, p)
    return "$".join((SCHEME, str(n), str(r), str(p), _b64(salt), _b64(key)))


def verify_password(password: str, encoded: str) -> bool:
    """True if `password` matches the encoded hash; False for a mismatch or a malformed hash."""
    try:
        n, r, p, salt, key = parse_hash(encoded)
    except ValueError:
        return False
    try:
        candidate = _derive(password, salt, n, r, p, len(key))
    except (ValueError, MemoryError):
        return False
    return hmac.compare_digest(candidate, key)


def parse_hash(encoded: str) -> tuple[int, int, int, bytes, bytes]:
    """Split an encoded hash into (n, r, p, salt, key); ValueError says what is wrong."""
    parts = encoded.split("$")
    if len(parts) != 6 or parts[0] != SCHEME:
        raise ValueError("expected scrypt$N$r$p$salt$key (make one with `cnc-gateway hash-password`)")
    try:
        n, r, p = int(parts[1]), int(parts[2]), int(parts[3])
        salt = base64.b64decode(parts[4], validate=True)
        key = base64.b64decode(parts[5], validate=True)
    except ValueError:
        raise ValueError("malformed scrypt hash: the numbers or the base64 parts do not parse") from None
    if n < 2 or n & (n - 1) or n > MAX_N:
        raise ValueError(f"scrypt N must be a power of two between 2 and {MAX_N}")
    if not 1 <= r <= 64 or not 1 <= p <= 16:
        raise ValueError("scrypt r must be 1..64 and p 1..16")
    if len(salt) < 8 or len(key) < 16:
        raise ValueError("the salt or the key of the scrypt hash is too short")
    return n, r, p, salt, key


def _derive(password: str, salt: bytes, n: int, r: int, p: int, length: int = KEY_BYTES) -> bytes:
    maxmem = 128 * r * (n + p + 2) + 1024 * 1024
    return hashlib.scrypt(password.encode("utf-8"), salt=salt, n=n, r=r, p=p, maxmem=maxmem, dklen=length)


def _b64(data: bytes) -> str:
    return base64.b64encode(data).decode("ascii")
