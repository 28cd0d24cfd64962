"""`connections:` of the two HTTP faces (the web console's `http:` and the MTConnect agent's `mtconnect:`),
which http_listener.py applies. Kept apart from the listener so that loading a configuration does not
import aiohttp."""

from __future__ import annotations

from typing import Annotated

from pydantic import Field

from gateway.settings.base import Strict


class ConnectionLimits(Strict):
    """How many connections an HTTP face (the console, the MTConnect agent) holds, and how long a connection
    may keep its place without a request. Slow-loris crowds are closed, not served, and the other doors
    keep their descriptors."""

    max: Annotated[int, Field(ge=1, le=100_000)] | None = Field(
        default=None,
        description="Connections at once; null: a quarter of the process's open-file limit (ulimit -n) less "
        "32, at most 1024. A larger value is lowered to that share (warned). At the cap, the oldest "
        "connection that waits (no request yet, or idle) makes room; when all are busy, new ones get 503",
    )
    per_address: int = Field(
        default=32,
        ge=1,
        le=100_000,
        description="Connections from one address at once; more are refused (503). Behind a reverse proxy "
        "every client comes from the proxy's address: raise it",
    )
    header_timeout: float = Field(
        default=10.0,
        gt=0,
        le=3600,
        description="Seconds a new connection has to send its request line and headers (its TLS handshake "
        "included); then it is closed (408)",
    )
    keepalive: float = Field(
        default=30.0,
        gt=0,
        le=3600,
        description="Seconds a connection stays open after a response, waiting for its next request "
        "(headers included)",
    )
