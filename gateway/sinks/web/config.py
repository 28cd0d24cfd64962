"""The gateway file's `http:` section: the web console, the REST API and `/metrics` (gateway/sinks/web/).

```yaml
http:
  host: 0.0.0.0          # every interface: the console is for the shop floor, /metrics for plant IT
  port: 8080
  tls: {cert: http-cert.pem, key: http-key.pem}   # optional, relative to the state directory (as inbox.tls)
  jobs_role: operator    # submit, retry, cancel and reprioritise jobs from the console or the API
  admin_role: null       # trust OPC UA certificates, see the effective configuration (null: the highest role)
  audit_role: null       # read the audit trail (null: admin_role)
  session_idle: 28800    # s a console session lasts without a request
  max_uploads: 4         # job uploads received at once
  body_timeout: 30       # s for a JSON or form body; the longest pause within an upload
  connections: {max: null, per_address: 32, header_timeout: 10, keepalive: 30}   # null: from ulimit -n
```

`http: null` turns the console, the API and the metrics off. Without the key the
section's defaults apply: the console listens on 0.0.0.0:8080. Like the OPC UA
server (4840) and the FTP inbox (2121), it is meant to be reached from the shop
network (a technician's laptop, Prometheus on another host); anonymous visitors
get `access.anonymous`'s role (viewer: they only look), so nothing anonymous may
change a machine unless the gateway file says so. Logins over plain HTTP cross the
network in clear: use `tls:` (or `host: 127.0.0.1` behind a reverse proxy) where
that matters.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import Annotated, Any, Protocol

from pydantic import Field, field_validator

from gateway.auth.ratelimit import LoginLimiter
from gateway.auth.users import UserDirectory
from gateway.settings.access import check_role_name
from gateway.settings.base import Strict
from gateway.sinks.http_limits import ConnectionLimits


class HttpTls(Strict):
    """HTTPS instead of HTTP. Files are relative to the state directory, as for the FTP inbox's TLS."""

    cert: str = Field(
        default="http-cert.pem", description="PEM certificate (chain), relative to the state directory"
    )
    key: str = Field(default="http-key.pem", description="PEM private key, relative to the state directory")


class HttpConfig(Strict):
    """The web console, the REST API (/api, described at /api/openapi.json) and /metrics."""

    host: str = Field(
        default="0.0.0.0",
        description="Address to listen on; 0.0.0.0 (every interface) so that the shop floor and monitoring "
        "reach it; anonymous visitors only get access.anonymous's role",
    )
    port: Annotated[int, Field(ge=0, le=65535)] = 8080
    tls: HttpTls | None = Field(default=None, description="Serve HTTPS; session cookies are then Secure")
    jobs_role: str = Field(
        default="operator", description="Lowest role that may submit, retry, cancel and reprioritise jobs"
    )
    admin_role: str | None = Field(
        default=None,
        description="Lowest role that may trust or reject OPC UA client certificates and read the effective "
        "configuration; null: the highest role",
    )
    session_idle: float = Field(
        default=8 * 3600.0, gt=0, description="Seconds a console session lasts without a request"
    )
    max_body: Annotated[int, Field(ge=1024)] = Field(
        default=1024 * 1024, description="Largest JSON request body, in bytes (uploads: inbox.max_file_size)"
    )
    body_timeout: float = Field(
        default=30.0,
        gt=0,
        le=3600,
        description="Seconds a JSON or form body (at most max_body) may take to arrive, and the longest "
        "pause within an upload; then the request is refused (408)",
    )
    max_uploads: int = Field(
        default=4,
        ge=1,
        le=1000,
        description="Job uploads (POST /api/jobs) received at once; more get 429. Each may write up to "
        "inbox.max_file_size to the inbox's staging folder",
    )
    audit_role: str | None = Field(
        default=None,
        description="Lowest role that may read the audit trail (/audit, /api/audit: every user's name and "
        "change); null: the admin role",
    )
    connections: ConnectionLimits = Field(
        default_factory=ConnectionLimits, description="Connection caps and timeouts of the console's port"
    )

    @field_validator("jobs_role", "admin_role", "audit_role")
    @classmethod
    def _roles(cls, value: str | None) -> str | None:
        return None if value is None else check_role_name(value)

    def admin(self, roles: list[str]) -> str:
        """The role that administers the gateway from the console."""
        return self.admin_role or roles[-1]

    def auditor(self, roles: list[str]) -> str:
        """The role that may read the audit trail."""
        return self.audit_role or self.admin(roles)


class ConsoleGateway(Protocol):
    """What the console reads of the gateway file (gateway/config/gateway.py `GatewayConfig` fits it)."""

    @property
    def roles(self) -> Sequence[str]: ...

    def user_directory(self, limiter: LoginLimiter | None = None) -> UserDirectory: ...


class ConsoleConfig(Protocol):
    """What the console reads of the whole configuration (gateway/config/loader.py `Config` fits it)."""

    @property
    def gateway(self) -> ConsoleGateway: ...

    @property
    def state_dir(self) -> Path: ...

    def effective(self) -> dict[str, Any]:
        """Every file's settings as JSON data, secrets masked (the console's Gateway page)."""
        ...
