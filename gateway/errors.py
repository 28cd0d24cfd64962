"""The gateway's own error hierarchy.

Third-party errors (asyncua, paho, aioftp, pydantic, yaml) are translated into
these at the adapter boundary, so the rest of the gateway never needs to know
which library raised what. Refused requests (RequestError: writes, method calls)
carry the OPC UA status code name that best describes them; every sink maps that
name to its own wire form.
"""

from __future__ import annotations

from dataclasses import dataclass


class GatewayError(Exception):
    """Base of every error the gateway raises on purpose."""


# --- configuration ---------------------------------------------------------------------------


@dataclass(frozen=True, slots=True)
class ConfigIssue:
    """One problem in a configuration file, located as precisely as we can."""

    file: str
    line: int | None
    key: str
    message: str

    def __str__(self) -> str:
        where = f"{self.file}:{self.line}" if self.line is not None else self.file
        key = f" {self.key}:" if self.key else ""
        return f"{where}:{key} {self.message}"


class ConfigError(GatewayError):
    """A configuration file is invalid. Carries every issue found, not only the first."""

    def __init__(self, issues: list[ConfigIssue]) -> None:
        self.issues = list(issues)
        super().__init__("\n".join(str(i) for i in self.issues))


# --- refused requests: writes, method calls ------------------------------------------------------


class RequestError(GatewayError):
    """A client's request (a write, a method call, an acknowledgement) was refused.

    `status` is the OPC UA StatusCode name for the refusal, `reason` the text users
    read; every sink maps the name to its own wire form. Refusals that writes and
    calls share (a role too low, a value of the wrong type) derive from this class
    directly; WriteError and CallError hold those of one kind only.
    """

    status = "BadInternalError"

    def __init__(self, reason: str, *, status: str | None = None) -> None:
        super().__init__(reason)
        self.reason = reason
        if status is not None:
            self.status = status


class AccessDenied(RequestError):
    status = "BadUserAccessDenied"


class TypeMismatch(RequestError):
    status = "BadTypeMismatch"


class OutOfRange(RequestError):
    status = "BadOutOfRange"


class InvalidState(RequestError):
    """The machine is not in a state that allows this (e.g. start while in Alarm)."""

    status = "BadInvalidState"


class MalformedRequest(RequestError):
    """A request that cannot be read at all: not UTF-8, malformed JSON, too large, no value."""

    status = "BadDecodingError"


class ControllerRefused(RequestError):
    """The controller answered with an error of its own (to a write, or to a program store operation)."""

    status = "BadWriteNotSupported"


class ControllerUnavailable(RequestError):
    """The controller could not be reached to carry out the request."""

    status = "BadNotConnected"


class WriteError(RequestError):
    """A write was refused for a reason only writes have."""


class UnknownVariable(WriteError):
    status = "BadNodeIdUnknown"


class NotWritable(WriteError):
    status = "BadNotWritable"


class CallError(RequestError):
    """A method call (a command, a Programs method, an alarm acknowledgement) was refused."""


class ArgumentsMissing(CallError):
    status = "BadArgumentsMissing"


class TooManyArguments(CallError):
    status = "BadTooManyArguments"


class InvalidArgument(CallError):
    """An argument names nothing the method can use (a file name the program store refuses)."""

    status = "BadInvalidArgument"


class NotFound(CallError):
    """What the call names does not exist (a program not in the controller's store)."""

    status = "BadNotFound"


class ConfirmTimeout(CallError):
    """The controller did not confirm in time (a command's completion condition never held)."""

    status = "BadTimeout"


# --- sources and sinks -------------------------------------------------------------------------


class SourceError(GatewayError):
    """A controller driver could not do its job (connect, browse, subscribe)."""

    def __init__(self, reason: str, *, status: str = "BadCommunicationError") -> None:
        super().__init__(reason)
        self.reason = reason
        self.status = status


class SinkError(GatewayError):
    """A sink could not start or serve (port in use, bad certificate, ...)."""


# --- codecs ------------------------------------------------------------------------------------


class CodecError(GatewayError, ValueError):
    """Bytes or text that do not follow the format they claim to."""


class AddressError(CodecError):
    """A `source` string that is not a usable OPC UA node id (gateway/codecs/opcua_nodeid.py)."""


# --- MQTT --------------------------------------------------------------------------------------


class BrokerError(SinkError):
    """The MQTT broker could not be reached, or the connection to it failed."""

    def __init__(self, reason: str) -> None:
        super().__init__(reason)
        self.reason = reason


class BrokerRefused(BrokerError):
    """The broker answered, and refused us: bad credentials, not authorised, client id rejected."""


# --- durable stores (gateway/sqlite_file.py, gateway/postgres.py) ------------------------------


class StoreError(GatewayError):
    """A state file (SQLite) or database (PostgreSQL) cannot be opened, read or written; the message names
    the file, or the database's URL without its password."""


class AlarmStoreError(StoreError):
    """The alarm file cannot be opened or written (gateway/alarms/store.py)."""


class AuditStoreError(StoreError):
    """The audit table cannot be opened or written (a missing one, opened with create=False, too)."""


class TransferLogError(StoreError):
    """The DNC transfer log cannot be opened or written (gateway/transports/dnc/transfers.py)."""


class LeaseError(StoreError):
    """The lease table (gateway/shards/leases.py) cannot be reached, or a lease is lost: expired, or taken."""


class StaleFence(LeaseError):
    """A fencing token is no longer its machine's current lease: its holder must not act on the machine."""


# --- jobs --------------------------------------------------------------------------------------


class JobError(GatewayError):
    """A job operation was refused: unknown job, or a state that does not allow it."""


class JobStoreError(StoreError, JobError):
    """The job queue's database (PostgreSQL) cannot be reached or failed; a JobError too, so that the
    callers that refuse a job operation refuse this one the same way."""


class PathRefused(GatewayError):
    """A path or file name the job inbox will not serve. `code` is the FTP reply code, `reason` its text."""

    def __init__(self, reason: str, code: str = "550") -> None:
        super().__init__(reason)
        self.reason = reason
        self.code = code


class DeliveryError(GatewayError):
    """The controller's program store could not take (or give) a program.

    `reply` is the FTP server's own answer when there was one (`550 disk full`);
    `permanent` marks refusals that retrying cannot cure (a name the store rejects).
    """

    def __init__(self, reason: str, *, reply: str | None = None, permanent: bool = False) -> None:
        super().__init__(reason)
        self.reason = reason
        self.reply = reply
        self.permanent = permanent


class ProgramNotFound(DeliveryError):
    """The controller's program store has no program of that name."""
