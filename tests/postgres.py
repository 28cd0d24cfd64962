"""A real PostgreSQL for the tests: one fresh database per test, created and dropped around it.

The server is the one at 127.0.0.1:5432 (CNC_TEST_POSTGRES overrides the admin URL). When it
cannot be reached, a test that needs it fails under CI (CI=true: the server is part of the
set-up, .ci/run checks it) and is skipped with the reason elsewhere.
"""

from __future__ import annotations

import os
import uuid
from collections.abc import Iterator
from contextlib import contextmanager
from urllib.parse import urlsplit, urlunsplit

import psycopg
import pytest

ADMIN_URL = os.environ.get("CNC_TEST_POSTGRES", "postgresql://postgres@127.0.0.1:5432/postgres")
HOW = (
    "start it (Debian: `pg_ctlcluster 15 main start` or `service postgresql start`) with trust"
    " authentication for 127.0.0.1, or point CNC_TEST_POSTGRES at an admin URL"
)


def _admin() -> psycopg.Connection[tuple[object, ...]]:
    return psycopg.connect(ADMIN_URL, autocommit=True, connect_timeout=5)


def unreachable() -> str | None:
    """Why PostgreSQL cannot be used for tests, or None when it can."""
    try:
        with _admin():
            return None
    except psycopg.Error as exc:
        first = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
        return f"PostgreSQL at {ADMIN_URL} is not reachable ({first}): {HOW}"


def require() -> None:
    why = unreachable()
    if why is None:
        return
    if os.environ.get("CI", "").lower() in ("1", "true", "yes"):
        pytest.fail(why, pytrace=False)
    pytest.skip(why)


def url_of(database: str) -> str:
    parts = urlsplit(ADMIN_URL)
    return urlunsplit((parts.scheme, parts.netloc, f"/{database}", parts.query, parts.fragment))


@contextmanager
def database() -> Iterator[str]:
    """A new, empty database; its URL. Dropped afterwards, whatever connections are still open."""
    require()
    name = f"cnc_test_{uuid.uuid4().hex[:16]}"
    with _admin() as admin:
        admin.execute(f'CREATE DATABASE "{name}"'.encode())
    try:
        yield url_of(name)
    finally:
        with _admin() as admin:
            admin.execute(f'DROP DATABASE IF EXISTS "{name}" WITH (FORCE)'.encode())
