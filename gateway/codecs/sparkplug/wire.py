"""The one module that calls the protobuf runtime: Payload bytes in and out, its errors translated.

The message classes come from sparkplug_b_pb2 (generated, never edited); parsing is the only
call that can fail on foreign bytes, and it fails here as MalformedPayload. Nesting deeper than
the runtime's recursion limit (100) is malformed too.
"""

from __future__ import annotations

from google.protobuf.message import DecodeError, EncodeError

from gateway.codecs.sparkplug.errors import MalformedPayload, Unencodable
from gateway.codecs.sparkplug.limits import MAX_PAYLOAD
from gateway.codecs.sparkplug.sparkplug_b_pb2 import Payload

__all__ = ["MAX_PAYLOAD", "parse_payload", "serialize"]


def parse_payload(data: bytes, *, limit: int = MAX_PAYLOAD) -> Payload:
    """Parse a Sparkplug B Payload; MalformedPayload if the bytes are not one (or exceed `limit`)."""
    if not isinstance(data, (bytes, bytearray, memoryview)):
        raise MalformedPayload(f"a payload is bytes, got {type(data).__name__}")
    if len(data) > limit:
        raise MalformedPayload(f"{len(data)} bytes is more than the {limit} this edge node reads")
    payload = Payload()
    try:
        payload.ParseFromString(bytes(data))
    except DecodeError as exc:
        raise MalformedPayload(f"not a Sparkplug B protobuf payload ({exc})") from None
    except RecursionError:  # pragma: no cover - upb reports depth as DecodeError; pure-Python may not
        raise MalformedPayload("not a Sparkplug B protobuf payload (nested too deeply)") from None
    return payload


def serialize(payload: Payload) -> bytes:
    """The wire bytes of a Payload the codec built."""
    try:
        return payload.SerializeToString()
    except EncodeError as exc:  # pragma: no cover - proto2 without required fields always encodes
        raise Unencodable(f"the payload cannot be encoded ({exc})") from None
