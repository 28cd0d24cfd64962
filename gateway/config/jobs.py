"""Job queue settings: the mapping's `jobs:` section and the gateway file's `inbox:` section.

A mapping file's `jobs:` says how to reach the machine's program store (FTP on
the controller), how programs are checked before they go there, what happens to
duplicates and failures, and whether the program is selected and started once
delivered. The gateway file's `inbox:` configures the FTP server that nesting
software drops programs into: where it listens, who may log in, and its limits.
"""

from __future__ import annotations

import re
from typing import TYPE_CHECKING, Annotated, Any, Literal, Union

from pydantic import ByteSize, Discriminator, Field, Tag, field_validator, model_validator

from gateway.auth.passwords import parse_hash
from gateway.config.validation import ValidationRules
from gateway.settings.base import Backoff, Strict
from gateway.settings.names import check_variable_path
from gateway.transports import registry as transports
from gateway.transports.base import ControllerSettings
from gateway.transports.dnc.config import ControllerSerial
from gateway.transports.dnc.punch import PunchSettings

_ENV_NAME = re.compile(r"^[A-Za-z_][A-Za-z0-9_]*$")
_USER = re.compile(r"^[A-Za-z0-9_][A-Za-z0-9_.@\-]{0,63}$")
_MACHINE = re.compile(r"^[a-z0-9][a-z0-9_\-]{0,62}$")

ANONYMOUS_USERS = ("anonymous", "ftp")


Port = Annotated[int, Field(ge=1, le=65535)]
# "64 MiB", "512kB" or a number of bytes
Size = Annotated[ByteSize, Field(description="Bytes, or a size with a unit: 64MiB, 500kB")]


# --- the mapping file: jobs --------------------------------------------------------------------


# The controller's settings (`jobs.controller`): each transport's own model, from its folder
# (gateway/transports/registry.py); the union pydantic validates is built from the registry.


def _controller_type(value: Any) -> str:
    """Which controller model a `controller:` section is; files from before serial DNC have no `type`."""
    if isinstance(value, dict):
        return str(value.get("type", transports.DEFAULT))
    return str(getattr(value, "type", transports.DEFAULT))


def _controller_union() -> Any:
    """`jobs.controller` as pydantic validates it: the registered transports' models, tagged by type."""
    members = tuple(Annotated[spec.settings, Tag(spec.type)] for spec in transports.ordered())
    return Annotated[Union[members], Discriminator(_controller_type)]  # noqa: UP007 - built from a tuple


if TYPE_CHECKING:  # what the core may read of any controller's settings; each transport narrows to its own
    Controller = ControllerSettings
else:
    Controller = _controller_union()


class Retry(Backoff):
    """Exponential backoff between delivery attempts, in seconds."""

    initial: float = Field(default=2.0, gt=0)
    max: float = Field(default=60.0, gt=0)


class ReadyCondition(Strict):
    """A mapped variable that must hold a value before the gateway selects and starts a program."""

    path: str = Field(description="Mapped variable, e.g. Machine/State")
    equals: bool | int | float | str = Field(description="The value that means ready, e.g. 0 for Idle")

    @field_validator("path")
    @classmethod
    def _path(cls, path: str) -> str:
        return check_variable_path(path)


class AutoStart(Strict):
    """What happens on the machine after a program is delivered."""

    select: str | None = Field(
        default=None, description="String variable the program is written to, to select it"
    )
    select_value: Literal["name", "path", "program"] = Field(
        default="name",
        description="What is written to select: the file name, its full path on the controller, "
        "or the program name the validator found (O-number)",
    )
    start: str | None = Field(
        default=None, description="Boolean variable written true to start the selected program"
    )
    ready: ReadyCondition | None = Field(
        default=None, description="Wait for this before selecting; without it, select and start at once"
    )
    ready_timeout: float = Field(
        default=3600.0, gt=0, description="Seconds to wait for ready before giving up"
    )
    confirm_timeout: float = Field(
        default=15.0, gt=0, description="Seconds for the machine to leave the ready state after start"
    )

    @field_validator("select", "start")
    @classmethod
    def _paths(cls, path: str | None) -> str | None:
        return None if path is None else check_variable_path(path)

    @model_validator(mode="after")
    def _something(self) -> AutoStart:
        if self.select is None and self.start is None:
            raise ValueError("auto needs select, start or both")
        return self


class BackupSettings(Strict):
    """Programs.Backup: copies of controller programs in the gateway's backups/<machine>/ folder. The method
    needs the operator role; these bound how much one caller can make it write."""

    keep: int = Field(
        default=50,
        ge=0,
        le=100_000,
        description="Newest Programs.Backup copies kept per machine (older ones are deleted); 0: no limit by "
        "count. Punched programs filed there (punch.backup) are not counted or deleted",
    )
    max_age_days: float = Field(
        default=90.0, ge=0, description="Copies older than this are deleted at the next backup; 0: never"
    )
    per_hour: int = Field(
        default=30, ge=1, le=100_000,
        description="Backup calls per machine in any hour; more are refused (BadTooManyOperations)",
    )  # fmt: skip


class JobsConfig(Strict):
    """The machine's job queue: its program store, checks, duplicates, retries and auto-start."""

    controller: Controller
    validation: ValidationRules = Field(default_factory=ValidationRules)
    duplicates: Literal["skip", "replace"] = Field(
        default="skip",
        description="The same content arriving while an earlier copy still waits: skip the new one, "
        "or replace (cancel) the waiting one",
    )
    max_attempts: int = Field(
        default=5, ge=1, le=1000, description="Delivery attempts before a job is FAILED"
    )
    retry: Retry = Retry()
    verify: Literal["size", "hash"] = Field(
        default="size",
        description="After delivery, compare the size (SIZE or a listing), or download it back and hash",
    )
    auto: AutoStart | None = Field(default=None, description="Select and start the program once delivered")
    backups: BackupSettings = Field(
        default_factory=BackupSettings, description="Programs.Backup's retention and rate (operator role)"
    )
    punch: PunchSettings | None = Field(
        default=None,
        description="Serial lines: store programs the operator punches, answer remote requests",
    )
    mqtt_retained_jobs: int = Field(
        default=100, ge=0, le=100_000,
        description="Ended jobs (DELIVERED, REJECTED, FAILED, CANCELLED) whose MQTT jobs/<id> record "
        "stays retained; older ones are cleared from the broker. 0: cleared as soon as they end",
    )  # fmt: skip

    @model_validator(mode="after")
    def _punch_needs_a_line(self) -> JobsConfig:
        if self.punch is not None and not isinstance(self.controller, ControllerSerial):
            raise ValueError("punch: needs a serial controller (jobs.controller type: serial)")
        return self

    @model_validator(mode="after")
    def _auto_fits(self) -> JobsConfig:
        serial = isinstance(self.controller, ControllerSerial)
        if serial and self.auto is not None and self.auto.select_value == "path":
            raise ValueError("auto.select_value: path needs a program folder; a serial line has none")
        return self


# --- the gateway file: inbox --------------------------------------------------------------------


class FtpAccount(Strict):
    """One inbox login: a user, its secret, and the machines it may send programs to."""

    user: str = Field(description="Login name")
    password_hash: str | None = Field(
        default=None, description="scrypt hash from `cnc-gateway hash-password`"
    )
    password_env: str | None = Field(
        default=None, description="Name of an environment variable holding the password"
    )
    machines: list[str] = Field(
        default_factory=lambda: ["*"], description="Machines it may write to; * for all"
    )

    @field_validator("user")
    @classmethod
    def _user(cls, user: str) -> str:
        if not _USER.match(user):
            raise ValueError(f"user {user!r} must be 1-64 letters, digits, '_', '.', '@' or '-'")
        if user.lower() in ANONYMOUS_USERS:
            raise ValueError(f"{user!r} is the anonymous login; use anonymous: true instead")
        return user

    @field_validator("password_hash")
    @classmethod
    def _hash(cls, value: str | None) -> str | None:
        if value is not None:
            parse_hash(value)
        return value

    @field_validator("password_env")
    @classmethod
    def _env(cls, value: str | None) -> str | None:
        if value is not None and not _ENV_NAME.match(value):
            raise ValueError(f"{value!r} is not an environment variable name")
        return value

    @field_validator("machines")
    @classmethod
    def _machines(cls, machines: list[str]) -> list[str]:
        return check_machine_list(machines)

    @model_validator(mode="after")
    def _one_secret(self) -> FtpAccount:
        if (self.password_hash is None) == (self.password_env is None):
            raise ValueError(f"account {self.user!r} needs exactly one of password_hash and password_env")
        return self


def check_machine_list(machines: list[str]) -> list[str]:
    for name in machines:
        if name != "*" and not _MACHINE.match(name):
            raise ValueError(f"{name!r} is not a machine name (or * for every machine)")
    return machines


class PortRange(Strict):
    min: Port
    max: Port

    @model_validator(mode="after")
    def _ordered(self) -> PortRange:
        if self.max < self.min:
            raise ValueError("passive port range max must not be below min")
        return self

    @property
    def ports(self) -> range:
        return range(self.min, self.max + 1)


class InboxTls(Strict):
    """Implicit FTPS (TLS from the first byte, usually port 990). Files are relative to the state directory."""  # noqa: E501 - it is the schema's description

    cert: str = Field(
        default="inbox-cert.pem", description="PEM certificate (chain), relative to the state directory"
    )
    key: str = Field(default="inbox-key.pem", description="PEM private key, relative to the state directory")


class InboxConfig(Strict):
    """The FTP server that nesting software drops programs into: one folder per machine."""

    enabled: bool = Field(default=True, description="Serve the inbox when some machine has a jobs section")
    host: str = Field(default="0.0.0.0", description="Address to listen on")
    port: Annotated[int, Field(ge=0, le=65535)] = 2121
    passive_ports: PortRange | None = Field(default=None, description="Ports for passive data connections")
    passive_address: str | None = Field(
        default=None, description="IPv4 address announced in PASV replies, when clients reach us through NAT"
    )
    pasv_promiscuous: bool = Field(
        default=False,
        description="Take a passive data connection from any address (vsftpd's option); false: only from "
        "the address of the session's control connection, so nobody else can slip their bytes into an upload",
    )
    accounts: list[FtpAccount] = Field(default_factory=list)
    anonymous: bool = Field(default=False, description="Allow the anonymous login (any password)")
    anonymous_machines: list[str] = Field(
        default_factory=lambda: ["*"], description="Machines the anonymous login may write to"
    )
    max_file_size: Size = Field(default=ByteSize(64 * 1024 * 1024), description="Largest program accepted")
    max_files_per_session: int = Field(default=200, ge=1, description="Uploads allowed per login session")
    max_connections: int = Field(default=32, ge=1, description="Simultaneous FTP sessions")
    max_connections_per_address: int = Field(
        default=8,
        ge=1,
        description="Simultaneous FTP sessions from one address (never more than max_connections - 1, so "
        "that one address cannot take every slot)",
    )
    login_timeout: float = Field(
        default=30.0, gt=0, description="Seconds a session has to log in before it is closed"
    )
    idle_timeout: float = Field(
        default=300.0, gt=0, description="Seconds without a command before a session is closed"
    )
    transfer_timeout: float = Field(default=60.0, gt=0, description="Seconds a data transfer may stall")
    temp_suffixes: list[str] = Field(
        default_factory=lambda: [".part", ".tmp", ".filepart"],
        description="Uploads with these suffixes (or in a machine's tmp/ folder) wait for a rename "
        "to become jobs",
    )
    temp_max_age: float = Field(
        default=3600.0,
        gt=0,
        description="Seconds after its last write that a temporary upload nobody renamed is deleted",
    )
    reply_within: float = Field(
        default=10.0,
        gt=0,
        description="Seconds to wait for validation before the upload is answered; "
        "longer checks finish in the background",
    )
    tls: InboxTls | None = Field(default=None, description="Serve implicit FTPS instead of plain FTP")

    @field_validator("anonymous_machines")
    @classmethod
    def _machines(cls, machines: list[str]) -> list[str]:
        return check_machine_list(machines)

    @field_validator("temp_suffixes")
    @classmethod
    def _suffixes(cls, suffixes: list[str]) -> list[str]:
        for suffix in suffixes:
            if not suffix.startswith(".") or len(suffix) < 2 or "/" in suffix or not suffix.isprintable():
                raise ValueError(f"temp suffix {suffix!r} must look like .part")
        return [s.lower() for s in suffixes]

    @field_validator("accounts")
    @classmethod
    def _unique(cls, accounts: list[FtpAccount]) -> list[FtpAccount]:
        seen: set[str] = set()
        for account in accounts:
            if account.user in seen:
                raise ValueError(f"account {account.user!r} is defined twice")
            seen.add(account.user)
        return accounts


def machines_allowed(patterns: list[str], machine: str) -> bool:
    return "*" in patterns or machine in patterns
