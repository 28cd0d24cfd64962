"""The gateway's own error hierarchy.

Third-party errors (asyncua, paho, aioftp, pydantic, yaml) are translated into
these at the adapter boundary, so the rest of the gateway never needs to know
which library raised what. Write errors carry the OPC UA status code name that
best describes them; every sink maps that name to its own wire form.
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


# --- writes ----------------------------------------------------------------------------------


class WriteError(GatewayError):
    """A write was refused. `status` is the OPC UA StatusCode name for the refusal."""

    status = "BadInternalError"

    def __init__(self, reason: str, *, status: str | None = None) -> None:
        super().__init__(reason)
        self.reason = reason
        if status is not None:
            self.status = status


class UnknownVariable(WriteError):
    status = "BadNodeIdUnknown"


class NotWritable(WriteError):
    status = "BadNotWritable"


class AccessDenied(WriteError):
    status = "BadUserAccessDenied"


class TypeMismatch(WriteError):
    status = "BadTypeMismatch"


class OutOfRange(WriteError):
    status = "BadOutOfRange"


class ArgumentsMissing(WriteError):
    status = "BadArgumentsMissing"


class TooManyArguments(WriteError):
    status = "BadTooManyArguments"


class InvalidState(WriteError):
    """The machine is not in a state that allows this (e.g. start while in Alarm)."""

    status = "BadInvalidState"


class Timeout(WriteError):
    """The controller did not confirm in time."""

    status = "BadTimeout"


class ControllerRefused(WriteError):
    """The controller answered the write with an error of its own."""

    status = "BadWriteNotSupported"


class ControllerUnavailable(WriteError):
    """The controller could not be reached to carry out the write."""

    status = "BadNotConnected"


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


# --- MQTT --------------------------------------------------------------------------------------


class BadWriteRequest(WriteError):
    """A write request that cannot be read at all: not UTF-8, malformed JSON, too large, no value."""

    status = "BadDecodingError"


class BrokerError(SinkError):
    """The MQTT broker could not be reached, or the connection to it failed."""

    def __init__(self, reason: str) -> None:
        super().__init__(reason)
        self.reason = reason


class BrokerRefused(BrokerError):
    """The broker answered, and refused us: bad credentials, not authorised, client id rejected."""


# --- jobs --------------------------------------------------------------------------------------


class JobError(GatewayError):
    """A job operation was refused: unknown job, or a state that does not allow it."""


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
