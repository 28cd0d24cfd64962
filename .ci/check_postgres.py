"""Before `make test`: is the PostgreSQL the tests use reachable? Says what is missing and how to start it."""

from __future__ import annotations

import os
import sys

import psycopg

URL = os.environ.get("CNC_TEST_POSTGRES", "postgresql://postgres@127.0.0.1:5432/postgres")

try:
    with psycopg.connect(URL, connect_timeout=5) as conn:
        version = conn.execute("SHOW server_version").fetchone()
except psycopg.Error as exc:
    reason = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
    print(
        f"PostgreSQL is not reachable at {URL}: {reason}\n"
        "The job queue's and the shards' tests need a real server (tests/postgres.py). Start it with\n"
        "  sudo service postgresql start      (Debian: apt-get install postgresql)\n"
        "with trust authentication for 127.0.0.1 (pg_hba.conf: host all all 127.0.0.1/32 trust) and the\n"
        "user postgres, or set CNC_TEST_POSTGRES to an admin URL that may CREATE DATABASE.",
        file=sys.stderr,
    )
    raise SystemExit(1) from None
print(f"PostgreSQL {version[0] if version else '?'} at {URL}: reachable")
