"""The gateway file: settings shared by every machine, and the list of mapping files."""

from __future__ import annotations

from typing import TYPE_CHECKING, Literal

from pydantic import Field, ValidationInfo, field_validator

from gateway.auth.ratelimit import LoginLimiter
from gateway.auth.users import UserDirectory
from gateway.config.jobs import InboxConfig
from gateway.settings.access import (
    DEFAULT_ROLES,
    REFUSE,
    AccessConfig,
    UserConfig,
    check_access,
    check_roles,
    check_users,
    unknown_role,
)
from gateway.settings.sections import Sectioned, with_sections
from gateway.settings.urls import check_queue_url
from gateway.shards.static import LEASE, KOfN, parse_k_of_n
from gateway.sinks import registry as sinks
from gateway.sinks.mqtt.config import MqttConfig
from gateway.sinks.mtconnect.config import AgentConfig
from gateway.sinks.opcua.config import OpcUaServerConfig
from gateway.sinks.sparkplug.config import SparkplugConfig
from gateway.sinks.web.config import HttpConfig


class GatewayConfig(Sectioned):
    """Gateway-wide settings. A mapping file run on its own gets these defaults."""

    opcua: OpcUaServerConfig = OpcUaServerConfig()
    state_dir: str = Field(
        default="state", description="Where the gateway keeps its state; relative to this file"
    )
    machines: list[str] = Field(default_factory=list, description="Mapping files, relative to this file")
    shard: str | list[str] | None = Field(
        default=None,
        description="Serve only some machines of the fleet: K/N (2/4: every fourth machine in name order,"
        " from the second) or their names; `lease`: the machines this process holds a lease on in the"
        " queue's PostgreSQL database, taken over from a shard that stops renewing; absent: all of them",
    )
    lease_time: float = Field(
        default=10.0,
        ge=1.0,
        le=600.0,
        description="With shard: lease, seconds a lease lasts unrenewed: a dead shard's machines are served"
        " elsewhere after it and one renewal (a third of it)",
    )
    queue: str | None = Field(
        default=None,
        description="The job queue: a PostgreSQL database that shards share (postgresql://user@host/db;"
        " the password from PGPASSWORD or ~/.pgpass); absent: a SQLite file in the state directory",
    )
    audit: str | None = Field(
        default=None,
        description="The audit trail's table: a PostgreSQL database (postgresql://user@host/db; it may be the"
        " queue's), so that every shard of a fleet writes one trail; absent: a SQLite file in the state"
        " directory",
    )
    alarm_history: str | None = Field(
        default=None,
        description="The alarm history: a PostgreSQL database (postgresql://user@host/db; it may be the"
        " queue's), one for every shard of a fleet; absent: a SQLite file in the state directory",
    )
    log_level: Literal["debug", "info", "warning", "error"] = "info"
    inbox: InboxConfig = Field(
        default_factory=InboxConfig, description="The FTP inbox that nesting software drops programs into"
    )
    mqtt: MqttConfig | None = Field(
        default=None, description="The MQTT broker to publish to; absent: no MQTT"
    )
    sparkplug: SparkplugConfig | None = Field(
        default=None,
        description="Publish every machine as a Sparkplug B device of this edge node; absent: no Sparkplug",
    )
    mtconnect: AgentConfig | None = Field(
        default=None, description="The MTConnect agent (HTTP, port 5000 by default); absent: none"
    )
    # --- users, roles and access control (gateway/settings/access.py) ---
    roles: list[str] = Field(
        default_factory=lambda: list(DEFAULT_ROLES),
        min_length=1,
        description="Roles, lowest first; each may do what the ones before it may",
    )
    users: list[UserConfig] = Field(
        default_factory=list, description="OPC UA logins, with scrypt password hashes"
    )
    access: AccessConfig = Field(
        default_factory=AccessConfig,
        validate_default=True,  # its default roles must exist too
        description="Role enforcement, anonymous logins, roles of MQTT, COPYDATA and job writers",
    )
    http: HttpConfig | None = Field(
        default_factory=HttpConfig,
        description="The web console, REST API and /metrics (gateway/sinks/web/config.py); null: off",
    )

    @field_validator("shard")
    @classmethod
    def _shard(cls, shard: str | list[str] | None) -> str | list[str] | None:
        if shard == LEASE:
            return shard
        if isinstance(shard, str):
            parse_k_of_n(shard)
        elif isinstance(shard, list):
            if not shard:
                raise ValueError("lists no machines (leave shard out to serve them all)")
            repeated = sorted({name for name in shard if shard.count(name) > 1})
            if repeated:
                raise ValueError(f"names {', '.join(repeated)} more than once")
        return shard

    @property
    def leased(self) -> bool:
        """`shard: lease`: every machine is loaded, and served while this process holds its lease."""
        return self.shard == LEASE

    def shard_of(self) -> KOfN | list[str] | None:
        """The static `shard:` this process serves, parsed (None: the whole fleet, or by lease)."""
        if self.shard == LEASE:
            return None
        return parse_k_of_n(self.shard) if isinstance(self.shard, str) else self.shard

    @field_validator("queue")
    @classmethod
    def _queue(cls, queue: str | None) -> str | None:
        return None if queue is None else check_queue_url(queue)

    @field_validator("audit")
    @classmethod
    def _audit(cls, audit: str | None) -> str | None:
        return None if audit is None else check_queue_url(audit, "audit")

    @field_validator("alarm_history")
    @classmethod
    def _alarm_history(cls, url: str | None) -> str | None:
        return None if url is None else check_queue_url(url, "alarm_history")

    @field_validator("roles")
    @classmethod
    def _roles(cls, roles: list[str]) -> list[str]:
        return check_roles(roles)

    @field_validator("users")
    @classmethod
    def _users(cls, users: list[UserConfig], info: ValidationInfo) -> list[UserConfig]:
        roles = info.data.get("roles")
        return users if roles is None else check_users(users, roles)

    @field_validator("access")
    @classmethod
    def _access(cls, access: AccessConfig, info: ValidationInfo) -> AccessConfig:
        roles, users = info.data.get("roles"), info.data.get("users")
        return access if roles is None or users is None else check_access(access, roles, users)

    @field_validator("sparkplug")
    @classmethod
    def _sparkplug(cls, value: SparkplugConfig | None, info: ValidationInfo) -> SparkplugConfig | None:
        if value is not None and "mqtt" in info.data:
            value.connection(info.data["mqtt"])  # a broker of its own, or the mqtt: section's
        return value

    @field_validator("http")
    @classmethod
    def _http(cls, http: HttpConfig | None, info: ValidationInfo) -> HttpConfig | None:
        roles = info.data.get("roles")
        if http is None or roles is None:
            return http
        for key in ("jobs_role", "admin_role", "audit_role"):
            problem = unknown_role(getattr(http, key), roles) if getattr(http, key) else None
            if problem:
                raise ValueError(f"http.{key}: {problem}")
        return http

    def login_limiter(self) -> LoginLimiter:
        """A new failed-login lockout (`access.lockout`). The gateway builds one and gives it to every door
        that checks passwords (gateway/auth/lockout.py): a lockout is per address, not per door."""
        lockout = self.access.lockout
        return LoginLimiter(lockout.failures, lockout.window, lockout.duration)

    def user_directory(self, limiter: LoginLimiter | None = None) -> UserDirectory:
        """The users, the anonymous role and the lockout, as gateway/auth/users.py checks logins.

        `limiter`: the gateway's shared lockout; without one, a new one (a door on its own)."""
        access = self.access
        refuse = access.anonymous == REFUSE
        return UserDirectory(
            {u.name: (u.password_hash, u.role) for u in self.users},
            anonymous_role=None if refuse else access.anonymous,
            anonymous_allowed=not refuse,
            limiter=limiter if limiter is not None else self.login_limiter(),
        )


if not TYPE_CHECKING:  # with the keys sinks registered after the registry came add
    GatewayConfig = with_sections(GatewayConfig, sinks.gateway_sections())
