"""Errors of the Sparkplug B codec: one class per way a topic, payload or value can be wrong.

Every error is a `SparkplugError` (a `gateway.errors.CodecError`, hence also a ValueError)
with a stable `kind` string, for logs and refusal counters, and `metric`: the metric the
fault is about (its name, or `alias 7` when only the alias is known), or None when the
fault is the message's own. Callers that only care about "bad input" catch
`SparkplugError`; tests and the sink's counters tell the cases apart by class or `kind`.
"""

from __future__ import annotations

from gateway.errors import CodecError


class SparkplugError(CodecError):
    """A Sparkplug topic, payload or value is malformed, or a value cannot be encoded."""

    kind = "sparkplug"

    def __init__(self, message: str, *, metric: str | None = None) -> None:
        super().__init__(message)
        self.message = message
        self.metric = metric

    def __str__(self) -> str:
        if self.metric is None:
            return self.message
        return f"{self.metric}: {self.message}"


# --- topics ------------------------------------------------------------------------------------


class BadId(SparkplugError):
    """A group, edge node, device or host id that Sparkplug does not allow (empty, '+', '#', '/')."""

    kind = "bad_id"


class BadTopic(SparkplugError):
    """A topic outside the Sparkplug B namespace, or not of its shape."""

    kind = "bad_topic"


# --- decoding ----------------------------------------------------------------------------------


class MalformedPayload(SparkplugError):
    """The bytes are not a Sparkplug B protobuf Payload (or are larger than we read)."""

    kind = "malformed_protobuf"


class UnknownAlias(SparkplugError):
    """A command names a metric by an alias that the birth did not bind."""

    kind = "unknown_alias"


class UnknownMetric(SparkplugError):
    """A command names a metric that the birth did not announce (or names none at all)."""

    kind = "unknown_metric"


class WrongDatatype(SparkplugError):
    """A datatype, or a value field, that does not match the metric's birth datatype."""

    kind = "wrong_datatype"


class BadValue(SparkplugError):
    """A value of the right field that cannot be read: out of the type's range, broken array
    bytes, text that is not UTF-8, a null or a missing value where a value is needed."""

    kind = "bad_value"


class BadCommand(SparkplugError):
    """A command message that is well formed but not something an edge node carries out
    (no metrics, a historical value, a rebirth request of false)."""

    kind = "bad_command"


class BadState(SparkplugError):
    """A host application's STATE payload that is neither 3.0 JSON nor 2.2 ONLINE/OFFLINE."""

    kind = "bad_state"


# --- encoding ----------------------------------------------------------------------------------


class Unencodable(SparkplugError):
    """A Python value that the metric's datatype cannot carry (the sink's mistake, not the wire's)."""

    kind = "unencodable"


class BadBirth(SparkplugError):
    """A birth that would break the specification: duplicate names or aliases, a reserved name."""

    kind = "bad_birth"
