"""Passwords that cnc-gateway itself publishes (examples, the demo, the compose file): never good enough.

Anyone who has read the README knows them, so an installation that kept one has
no password at all. The gateway refuses them at start-up (gateway/config/loader.py
names the file and the key) and `cnc-gateway hash-password` will not hash them.

A hash cannot be compared by its text (each has its own salt), so it is checked
against each of these passwords: one scrypt per password, run on a few threads,
and remembered per hash for the life of the process.
"""

from __future__ import annotations

from collections.abc import Iterable
from concurrent.futures import ThreadPoolExecutor
from functools import lru_cache

from gateway.auth.passwords import verify_password

# Every password that appears in the project's docs, examples and demo: keep this the one list.
KNOWN_PASSWORDS: tuple[str, ...] = (
    "change-me",  # the example gateway file and docker-compose.yml, before issue 23
    "nesting",  # the demo's inbox account (README walkthrough)
    "viewer",  # the demo's users: the password is the user name (README walkthrough)
    "operator",
    "engineer",
    "admin",
    "simulator",  # the simulator's FTP store (its default)
)
_THREADS = 4


def is_known(password: str) -> bool:
    """Whether `password` is one of the published ones (as written: a hash can only be checked so too)."""
    return password in KNOWN_PASSWORDS


@lru_cache(maxsize=256)
def known_password_of(encoded: str) -> str | None:
    """The published password `encoded` is a hash of, or None. Blocking (scrypt, once per known password)."""
    for password in KNOWN_PASSWORDS:
        if verify_password(password, encoded):
            return password
    return None


def known_passwords_of(hashes: Iterable[str]) -> dict[str, str]:
    """{hash: the published password it is a hash of} for those of `hashes` that are one; checked on a few
    threads (hashlib's scrypt releases the GIL), so that many accounts cost start-up little."""
    unique = list(dict.fromkeys(hashes))
    if len(unique) <= 1:
        found = [known_password_of(h) for h in unique]
    else:
        with ThreadPoolExecutor(min(_THREADS, len(unique)), thread_name_prefix="known-passwords") as pool:
            found = list(pool.map(known_password_of, unique))
    return {h: p for h, p in zip(unique, found, strict=True) if p is not None}
