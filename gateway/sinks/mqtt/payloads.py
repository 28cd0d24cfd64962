"""Payloads: samples to bytes, `/set` requests to values, results and status documents to bytes.

Pure functions, no I/O. The JSON form is
`{"value": …, "ts": "<ISO-8601 source time>", "quality": "good", "unit": "mm"}`,
plus `"status"` (the OPC UA status name) and `"reason"` when the quality is not
good; the value is then the last one the controller reported, as the tree keeps
it. The raw form is the value alone, as text, for dashboards that cannot parse
JSON (it cannot express quality; the machine's status topic still does).

Encoding runs for every change (thousands a second), so the common scalar
cases avoid `json.dumps` and its encoder set-up.
"""

from __future__ import annotations

import functools
import json
import math
from collections.abc import Mapping
from datetime import UTC, datetime
from typing import Any

from gateway.errors import MalformedRequest
from gateway.model.events import Event
from gateway.model.sample import Sample
from gateway.model.types import TypeSpec, parse_text

_dumps = json.JSONEncoder(ensure_ascii=False, separators=(",", ":"), allow_nan=False).encode


@functools.lru_cache(maxsize=64)
def iso(ts: datetime) -> str:
    """ISO-8601 in UTC with milliseconds and a Z: what JavaScript's Date and most dashboards read.

    Cached: changes come in runs with one source time (a controller stamps a whole
    scan), so most calls are a lookup instead of a conversion.
    """
    utc = ts
    if utc.tzinfo is None:
        utc = utc.replace(tzinfo=UTC)
    elif utc.utcoffset():
        utc = utc.astimezone(UTC)
    return utc.replace(tzinfo=None).isoformat(timespec="milliseconds") + "Z"


def plain(value: Any) -> Any:
    """A tree value as JSON-ready data: DateTime as ISO text, non-finite floats as null."""
    t = type(value)
    if t is float:
        return value if math.isfinite(value) else None
    if t is int or t is bool or t is str or value is None:
        return value
    if isinstance(value, datetime):
        return iso(value)
    if isinstance(value, (list, tuple)):
        return [plain(v) for v in value]
    if isinstance(value, dict):
        return {str(k): plain(v) for k, v in value.items()}
    if isinstance(value, (bytes, bytearray)):
        return value.hex()
    if isinstance(value, float):
        return float(value) if math.isfinite(value) else None
    if isinstance(value, int):
        return int(value)
    return str(value)


def json_text(value: Any) -> str:
    """The JSON text of one value; fast for the scalar types most variables have."""
    t = type(value)
    if t is float:
        return repr(value) if math.isfinite(value) else "null"
    if t is bool:
        return "true" if value else "false"
    if t is int:
        return str(value)
    return _dumps(plain(value))


def unit_suffix(unit: str) -> str:
    """The constant tail of a variable's JSON payload, computed once per variable."""
    return f',"unit":{_dumps(unit)}}}' if unit else "}"


def encode_json(sample: Sample, suffix: str) -> bytes:
    """`{"value":…,"ts":…,"quality":…[,"status":…,"reason":…][,"unit":…]}` as UTF-8."""
    status = sample.status
    if status == "Good":
        ts = iso(sample.source_ts)
        return f'{{"value":{json_text(sample.value)},"ts":"{ts}","quality":"good"{suffix}'.encode()
    quality = sample.quality.value
    return (
        f'{{"value":{json_text(sample.value)},"ts":"{iso(sample.source_ts)}","quality":"{quality}",'
        f'"status":{_dumps(status)},"reason":{_dumps(sample.reason)}{suffix}'
    ).encode()


def encode_raw(value: Any) -> bytes:
    """The value alone as text: `12.5`, `true`, `part.nc`, `[1,2]`, an ISO time."""
    t = type(value)
    if t is str:
        text: str = value
        return text.encode()
    if isinstance(value, datetime):
        return iso(value).encode()
    return json_text(value).encode()


def encode_result(error: str | None = None, status: str | None = None) -> bytes:
    """The answer to a write: `{"ok":true}`, or `{"ok":false,"error":…,"status":…}`."""
    if error is None:
        return b'{"ok":true}'
    return _dumps({"ok": False, "error": error, "status": status or "BadInternalError"}).encode()


def encode_document(doc: dict[str, Any]) -> bytes:
    """A status document (gateway or machine) as compact JSON."""
    return _dumps(plain_dict(doc)).encode()


def encode_event(event: Event) -> bytes:
    """An event's payload with its time: `{"ts": …, …payload}` as compact JSON (a list payload: the list).

    No payload is an empty message: retained, it deletes the topic's retained message.
    """
    if event.payload is None:
        return b""
    if not isinstance(event.payload, Mapping):
        return _dumps(plain(list(event.payload))).encode()
    return _dumps({"ts": iso(event.ts), **plain_dict(dict(event.payload))}).encode()


def plain_dict(doc: dict[str, Any]) -> dict[str, Any]:
    return {key: plain(value) for key, value in doc.items()}


# --- write requests --------------------------------------------------------------------------


def decode_set(payload: bytes, spec: TypeSpec) -> Any:
    """The value a `/set` payload asks for: `{"value": …}`, or the value as plain text.

    A payload that starts with `{` is a JSON request, whatever the variable's
    type (write `{"value": "{…}"}` to set a text that starts with a brace).
    Plain text is read by the variable's type, as the CLI does. Raises a
    RequestError (MalformedRequest, TypeMismatch, OutOfRange) with a precise
    reason for anything else; never any other exception.
    """
    try:
        text = bytes(payload).decode("utf-8")
    except UnicodeDecodeError as exc:
        raise MalformedRequest(f"the payload is not UTF-8 text (byte {exc.start})") from None
    stripped = text.strip()
    if not stripped:
        raise MalformedRequest('the payload is empty; send {"value": …} or the value as text')
    if stripped.startswith("{"):
        return _json_request(stripped)
    try:
        return parse_text(spec, text)
    except (ValueError, RecursionError):  # not ours (those are RequestErrors): deep nesting, digit limits
        raise MalformedRequest(f"cannot read {stripped[:40]!r} as {spec}") from None


def _json_request(text: str) -> Any:
    try:
        request = json.loads(text)
    except RecursionError:
        raise MalformedRequest("malformed JSON: nested too deeply") from None
    except ValueError as exc:
        msg = getattr(exc, "msg", None) or str(exc)
        pos = getattr(exc, "pos", None)
        where = f" at character {pos}" if isinstance(pos, int) else ""
        raise MalformedRequest(f"malformed JSON: {msg}{where}") from None
    if not isinstance(request, dict):
        raise MalformedRequest('expected a JSON object {"value": …}')
    if "value" not in request:
        raise MalformedRequest('a JSON request needs a "value" key: {"value": …}')
    extra = sorted(k for k in request if k != "value")
    if extra:
        raise MalformedRequest(
            f'unknown key{"s" if len(extra) > 1 else ""} {", ".join(map(repr, extra))}; send {{"value": …}}'
        )
    return request["value"]
