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
