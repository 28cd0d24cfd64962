"""Addresses a settings model checks: an OPC UA endpoint, an HTTP base address."""

from __future__ import annotations

from urllib.parse import urlsplit


def check_endpoint(url: str, scheme: str = "opc.tcp") -> str:
    parts = urlsplit(url)
    if parts.scheme != scheme:
        raise ValueError(f"endpoint {url!r} must start with {scheme}://")
    try:
        port = parts.port
    except ValueError:
        raise ValueError(f"endpoint {url!r} has an invalid port") from None
    if not parts.hostname:
        raise ValueError(f"endpoint {url!r} has no host")
    if port is None:
        raise ValueError(f"endpoint {url!r} needs an explicit port, e.g. {scheme}://host:4840")
    return url


def check_url(url: str) -> str:
    parts = urlsplit(url)
    if parts.scheme not in ("http", "https"):
        raise ValueError(f"url {url!r} must start with http:// or https://")
    if not parts.hostname:
        raise ValueError(f"url {url!r} has no host")
    try:
        parts.port  # noqa: B018 - a bad port raises here
    except ValueError:
        raise ValueError(f"url {url!r} has an invalid port") from None
    if parts.query or parts.fragment:
        raise ValueError(f"url {url!r} must be the agent's base address, without ?query or #fragment")
    return url.rstrip("/")


def check_queue_url(url: str, key: str = "queue") -> str:
    """The gateway file's `queue:` (or `audit:`): a PostgreSQL URL naming a database (libpq's form; the
    password from the URL, or from PGPASSWORD / ~/.pgpass, which libpq reads itself)."""
    parts = urlsplit(url)
    shown = _without_password(url)
    if parts.scheme not in ("postgresql", "postgres"):
        raise ValueError(
            f"{shown!r} must be a PostgreSQL URL, postgresql://user@host:5432/database"
            f" (leave {key} out for the SQLite file in the state directory)"
        )
    try:
        parts.port  # noqa: B018 - a bad port raises here
    except ValueError:
        raise ValueError(f"{shown!r} has an invalid port") from None
    if not parts.path.strip("/"):
        raise ValueError(f"{shown!r} names no database: postgresql://host/database")
    if parts.fragment:
        raise ValueError(f"{shown!r} must not have a #fragment")
    return url


def _without_password(url: str) -> str:
    parts = urlsplit(url)
    if not parts.password:
        return url
    return url.replace(f":{parts.password}@", ":***@", 1)
