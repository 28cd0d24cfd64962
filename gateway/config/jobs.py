"""Job queue settings: the mapping's `jobs:` section and the gateway file's `inbox:` section.

A mapping file's `jobs:` says how to reach the machine's program store (FTP on
the controller), how programs are checked before they go there, what happens to
duplicates and failures, and whether the program is selected and started once
delivered. The gateway file's `inbox:` configures the FTP server that nesting
software drops programs into: where it listens, who may log in, and its limits.
"""

from __future__ import annotations

import re
from typing import Annotated, Any, Literal

from pydantic import ByteSize, Discriminator, Field, SecretStr, Tag, field_validator, model_validator

from gateway.auth.passwords import parse_hash
from gateway.config.punch import PunchSettings
from gateway.config.validation import ValidationRules
from gateway.settings.base import Backoff, Strict

_ENV_NAME = re.compile(r"^[A-Za-z_][A-Za-z0-9_]*$")
_USER = re.compile(r"^[A-Za-z0-9_][A-Za-z0-9_.@\-]{0,63}$")
_MACHINE = re.compile(r"^[a-z0-9][a-z0-9_\-]{0,62}$")
_VARIABLE_PATH = re.compile(r"^[A-Za-z0-9_][A-Za-z0-9_.\-]*(/[A-Za-z0-9_][A-Za-z0-9_.\-]*)*$")

ANONYMOUS_USERS = ("anonymous", "ftp")


Port = Annotated[int, Field(ge=1, le=65535)]
# "64 MiB", "512kB" or a number of bytes
Size = Annotated[ByteSize, Field(description="Bytes, or a size with a unit: 64MiB, 500kB")]


# --- the mapping file: jobs --------------------------------------------------------------------


class ControllerFtp(Strict):
    """The controller's FTP program store."""

    type: Literal["ftp"] = Field(default="ftp", description="ftp (the default) or serial")
    host: str = Field(min_length=1, description="Controller address")
    port: Port = 21
    user: str = Field(default="anonymous", min_length=1)
    password: SecretStr | None = Field(
        default=None, description="Use ${NAME} to take it from the environment"
    )
    folder: str = Field(default="/DATA/Programs", description="Where programs go on the controller")
    passive: Literal["auto", "epsv", "pasv"] = Field(
        default="auto",
        description="Passive mode command: auto tries EPSV, then PASV (active mode is not supported)",
    )
    tls: Literal["none", "implicit", "explicit"] = Field(
        default="none", description="FTPS: implicit (TLS from the first byte) or explicit (AUTH TLS)"
    )
    tls_verify: bool = Field(default=True, description="Check the controller's certificate")
    timeout: float = Field(default=10.0, gt=0, description="Seconds per connect, command and data block")
    upload: Literal["temp-rename", "direct"] = Field(
        default="temp-rename",
        description="temp-rename: upload under a temporary name, then rename (atomic); "
        "direct: for stores without RNFR/RNTO",
    )
    temp_suffix: str = Field(
        default=".tmp", min_length=1, description="Suffix of the temporary name on the controller"
    )
    rate_limit: Size | None = Field(
        default=None, description="Upload speed limit in bytes per second (slow controllers)"
    )

    @field_validator("folder")
    @classmethod
    def _folder(cls, folder: str) -> str:
        if not folder.startswith("/"):
            raise ValueError(
                f"folder {folder!r} must be an absolute path on the controller, e.g. /DATA/Programs"
            )
        if any(part == ".." for part in folder.split("/")) or "\\" in folder:
            raise ValueError(f"folder {folder!r} must not contain '..' or backslashes")
        return folder.rstrip("/") or "/"

    @field_validator("temp_suffix")
    @classmethod
    def _suffix(cls, suffix: str) -> str:
        if "/" in suffix or "\\" in suffix or not suffix.isprintable():
            raise ValueError("temp_suffix must be a plain, printable file name suffix such as .tmp")
        return suffix


_URL = re.compile(r"^(socket|rfc2217)://([A-Za-z0-9_.\-]+|\[[0-9A-Fa-f:.]+\]):(\d{1,5})/?$")
_DEVICE = re.compile(r"^(/dev/[A-Za-z0-9_.\-/]+|COM[0-9]{1,3}|\\\\\.\\COM[0-9]{1,3})$")


class AlarmWhen(Strict):
    """A mapped variable whose value says the controller is in alarm (a drip-feed then stops, FAILED)."""

    path: str = Field(description="Mapped variable, e.g. Machine/State")
    equals: bool | int | float | str = Field(description="The value that means alarm, e.g. 3")

    @field_validator("path")
    @classmethod
    def _path(cls, path: str) -> str:
        return check_variable_path(path)


class ControllerSerial(Strict):
    """A controller that takes programs over RS-232 (serial DNC), directly or through a device server."""

    type: Literal["serial"] = Field(description="serial: RS-232 DNC (load or drip-feed)")
    where: str = Field(
        description="A device path (/dev/ttyUSB0, COM3), rfc2217://host:port (a device server with "
        "RFC 2217) or socket://host:port (a raw TCP device server)"
    )
    baud: int = Field(default=9600, ge=50, le=4_000_000, description="Line speed, bits per second")
    bytesize: Literal[7, 8] = Field(default=7, description="Data bits (Fanuc: 7)")
    parity: Literal["none", "even", "odd"] = Field(default="even", description="Parity bit")
    stopbits: Literal[1, 2] = Field(default=2, description="Stop bits")
    handshake: Literal["xonxoff", "rtscts", "none"] = Field(
        default="xonxoff", description="Flow control: the controller's DC1/DC3 (xonxoff), RTS/CTS, or none"
    )
    eob: Literal["lf", "crlf"] = Field(default="lf", description="End of block the controller expects")
    leader: int = Field(default=20, ge=0, le=10_000, description="NULs sent before the first %")
    percent: bool = Field(default=True, description="Frame the program with % markers")
    chunk_size: int = Field(default=200, ge=1, le=65_536, description="Most bytes handed to the port at once")
    software_parity: bool = Field(
        default=False,
        description="Send a 7-bit line's parity bit as bit 7 of 8-bit bytes: only for a transparent 8-bit "
        "port (a device server whose serial port is set to 8N1/8N2, a pseudo-terminal). A device server "
        "whose port is set to the controller's format (7E2: the usual set-up) does the parity itself: "
        "leave it off. DC1/DC3 are obeyed whatever their bit 7 either way (docs/dnc-fanuc.md)",
    )
    mode: Literal["load", "drip"] = Field(
        default="load",
        description="load: the whole program into the controller's memory; drip: it runs as it arrives",
    )
    start: Literal["dc1", "now"] = Field(
        default="dc1", description="Start sending on the controller's first DC1 (its READ), or at once"
    )
    dc1_timeout: float = Field(
        default=60.0, gt=0, description="Seconds to wait for the controller's DC1 before the job fails"
    )
    stall_timeout: float = Field(
        default=600.0,
        gt=0,
        description="Seconds the controller may hold the line with DC3 before the job fails "
        "(a machine in feed hold)",
    )
    lead_time: float = Field(
        default=30.0, gt=0, description="Drip: seconds of cutting the controller's buffer should hold ahead"
    )
    buffer: int = Field(
        default=256, ge=8, le=16 * 1024 * 1024, description="The controller's receive buffer, bytes"
    )
    link: str | None = Field(
        default=None,
        pattern=r"^[A-Za-z0-9_.:-]{1,64}$",
        description="Drip: the device server or uplink this line shares with other machines' lines (any "
        "name; the same name in each machine's file); with link_capacity, the lines share it so that the "
        "machine whose buffer runs dry first is served first",
    )
    link_capacity: float | None = Field(
        default=None,
        gt=0,
        description="Characters per second the shared link carries for all its lines together",
    )
    rapid: float = Field(
        default=10_000.0, gt=0, description="Rapid rate, mm/min, for the run-time estimate while dripping"
    )
    lathe: bool = Field(
        default=False,
        description="Drip: the programs are a lathe's (Fanuc T, G-code system A: X a diameter, G98/G99 feed "
        "per minute/revolution, G50 S the spindle clamp), for the run-time estimate",
    )
    dwell_p: Literal["ms", "s"] = Field(
        default="ms",
        description="Drip: the unit of G4 P in the run-time estimate (Fanuc: ms; LinuxCNC: s). The "
        "estimate errs short, so ms is the default",
    )
    connect_timeout: float = Field(default=10.0, gt=0, description="Seconds to open the port")
    alarm_when: AlarmWhen | None = Field(
        default=None,
        description="A serial line cannot tell that the controller went into alarm; where the machine's "
        "state is mapped (from another driver), this stops a transfer when it says alarm",
    )
    dsr: bool = Field(
        default=False,
        description="A device path only: fail the transfer when DSR drops (the cable has DSR wired)",
    )

    @field_validator("where")
    @classmethod
    def _where(cls, where: str) -> str:
        if "://" in where:
            match = _URL.match(where)
            if match is None:
                raise ValueError(f"{where!r} is not like socket://host:port or rfc2217://host:port")
            if not 1 <= int(match.group(3)) <= 65535:
                raise ValueError(f"port {match.group(3)} in {where!r} is outside 1..65535")
            return where
        if not _DEVICE.match(where) or ".." in where.split("/"):
            raise ValueError(f"{where!r} is not a serial device path (/dev/ttyUSB0, COM3) or a URL")
        return where

    @model_validator(mode="after")
    def _line(self) -> ControllerSerial:
        if self.software_parity and (self.bytesize != 7 or self.parity == "none"):
            raise ValueError("software_parity needs bytesize 7 and parity even or odd")
        if self.link_capacity is not None and self.link is None:
            raise ValueError("link_capacity needs link: the name of the device server or uplink it is of")
        return self


def _controller_type(value: Any) -> str:
    """Which controller model a `controller:` section is; files from before serial DNC have no `type`."""
    if isinstance(value, dict):
        return str(value.get("type", "ftp"))
    return str(getattr(value, "type", "ftp"))


CONTROLLER_TAGS = ("ftp", "serial")
Controller = Annotated[
    Annotated[ControllerFtp, Tag("ftp")] | Annotated[ControllerSerial, Tag("serial")],
    Discriminator(_controller_type),
]


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


def check_variable_path(path: str) -> str:
    if not _VARIABLE_PATH.match(path):
        raise ValueError(f"{path!r} is not a variable path such as Control/Start")
    return path


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
