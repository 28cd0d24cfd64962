"""Requests and responses as the console's handlers see them: plain data, no web framework.

The aiohttp adapter (server.py) builds an `HttpRequest` for every request and
turns the `HttpResponse` a handler returns into the wire form; everything else
in this package is written against these types, so it can be tested without a
server and the framework stays in one module.

Every refusal is an `HttpResponse` made by `refusal()`: an HTTP status plus the
OPC UA status name and the reason, `{"error": {"status": …, "reason": …}}`.
"""

from __future__ import annotations

import json
import math
import re
from collections.abc import Awaitable, Callable, Mapping, Sequence
from dataclasses import dataclass, field
from datetime import UTC, datetime
from typing import Any
from urllib.parse import quote, unquote

from gateway.errors import MalformedRequest, RequestError

#: OPC UA status name -> HTTP status. Names not listed: 400 for Bad…, 500 for BadInternalError.
HTTP_STATUS = {
    "BadUserAccessDenied": 403,
    "BadIdentityTokenInvalid": 401,
    "BadNodeIdUnknown": 404,
    "BadNotFound": 404,
    "BadMethodInvalid": 404,
    "BadServiceUnsupported": 405,
    "BadNotWritable": 405,
    "BadDecodingError": 400,
    "BadTypeMismatch": 422,
    "BadOutOfRange": 422,
    "BadArgumentsMissing": 422,
    "BadTooManyArguments": 422,
    "BadInvalidArgument": 422,
    "BadInvalidState": 409,
    "BadConditionBranchAlreadyAcked": 409,
    "BadConditionBranchAlreadyConfirmed": 409,
    "BadRequestTooLarge": 413,
    "BadTooManyOperations": 429,
    "BadNotConnected": 503,
    "BadTimeout": 504,
    "BadWriteNotSupported": 502,
    "BadInternalError": 500,
}


@dataclass(frozen=True, slots=True)
class UploadedFile:
    """A multipart file part, already streamed to `path` (the job inbox's staging folder) by the adapter."""

    field: str
    filename: str
    path: Any  # pathlib.Path
    size: int
    sha256: str


@dataclass(slots=True)
class HttpRequest:
    method: str
    path: str  # decoded path, without the query
    query: Mapping[str, Sequence[str]]
    headers: Mapping[str, str]  # names in lower case
    cookies: Mapping[str, str]
    remote: str
    body: bytes = b""
    form: dict[str, str] = field(default_factory=dict)  # urlencoded or multipart text fields
    files: list[UploadedFile] = field(default_factory=list)
    params: dict[str, str] = field(default_factory=dict)  # from the route's {placeholders}
    secure: bool = False

    def arg(self, name: str, default: str | None = None) -> str | None:
        values = self.query.get(name)
        return values[-1] if values else default

    def args(self, name: str) -> list[str]:
        return list(self.query.get(name, ()))

    def json(self) -> Any:
        """The body as JSON; MalformedRequest (BadDecodingError) says why it is not."""
        if not self.body:
            raise MalformedRequest("the request has no body; send a JSON object")
        try:
            text = self.body.decode("utf-8")
        except UnicodeDecodeError as exc:
            raise MalformedRequest(f"the body is not UTF-8 text (byte {exc.start})") from None
        try:
            return json.loads(text)
        except RecursionError:
            raise MalformedRequest("malformed JSON: nested too deeply") from None
        except ValueError as exc:
            raise MalformedRequest(f"malformed JSON: {exc}") from None

    def json_object(self) -> dict[str, Any]:
        data = self.json()
        if not isinstance(data, dict):
            raise MalformedRequest("expected a JSON object")
        return data


@dataclass(frozen=True, slots=True)
class Admitted:
    """A request whose route and caller passed before its body was read (issue 23): the handler to run once
    the body is in, and how many file parts it takes (0: a file part is refused before it is written)."""

    handle: Callable[[HttpRequest], Awaitable[HttpResponse]]
    files: int = 0


@dataclass(slots=True)
class HttpResponse:
    status: int = 200
    body: bytes = b""
    content_type: str = "application/json"
    headers: dict[str, str] = field(default_factory=dict)
    cookies: list[str] = field(default_factory=list)  # complete Set-Cookie values


def plain(value: Any) -> Any:
    """A value as JSON-ready data: non-finite floats as text, times as ISO-8601 UTC, bytes as their size."""
    if value is None or isinstance(value, (bool, int, str)):
        return value
    if isinstance(value, float):
        return value if math.isfinite(value) else str(value)
    if isinstance(value, datetime):
        ts = value if value.tzinfo else value.replace(tzinfo=UTC)
        return ts.astimezone(UTC).isoformat().replace("+00:00", "Z")
    if isinstance(value, (bytes, bytearray)):
        return f"<{len(value)} bytes>"
    if isinstance(value, Mapping):
        return {str(k): plain(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [plain(v) for v in value]
    if hasattr(value, "value") and isinstance(value.value, str):  # enums
        return value.value
    return str(value)


def dumps(data: Any) -> bytes:
    return json.dumps(plain(data), ensure_ascii=False, separators=(",", ":"), allow_nan=False).encode()


def json_response(data: Any, status: int = 200) -> HttpResponse:
    return HttpResponse(status, dumps(data))


def refusal(status: str, reason: str, http: int | None = None) -> HttpResponse:
    code = http if http is not None else HTTP_STATUS.get(status, 400)
    return json_response({"error": {"status": status, "reason": reason}}, code)


def refused(exc: RequestError) -> HttpResponse:
    return refusal(exc.status, exc.reason)


def html_response(text: str, status: int = 200) -> HttpResponse:
    return HttpResponse(status, text.encode("utf-8"), "text/html; charset=utf-8")


MAX_NEXT = 500  # characters of a path to go back to after a login


def safe_path(value: str | None) -> str | None:
    """`value` as a Location that stays on this host, or None when it is anything but a clean path.

    A browser's URL parser drops tabs and newlines and reads `\\` as `/`, so `/\t/evil.example` is a
    network-path reference to evil.example (issue 23). Refused: anything not starting with a single `/`,
    control and whitespace characters, backslashes, `//` anywhere in the path, malformed `%` escapes, and
    the same after percent-decoding (twice encoded included). Non-ASCII characters are percent-encoded.
    """
    if not value or len(value) > MAX_NEXT:
        return None
    seen = value
    for _ in range(3):  # `%252F` is `%2F` is `/`
        if not _clean_path(seen):
            return None
        try:
            decoded = unquote(seen, errors="strict")
        except UnicodeDecodeError:
            return None
        if decoded == seen:
            return quote(value, safe="".join(chr(c) for c in range(0x21, 0x7F)))
        seen = decoded
    return None  # still encoded after three rounds: no console path is


def _clean_path(text: str) -> bool:
    path = text.split("?", 1)[0].split("#", 1)[0]
    return (
        text.startswith("/")
        and "//" not in path
        and "\\" not in text
        and text.isprintable()
        and not any(c.isspace() for c in text)
        and not _BAD_ESCAPE.search(text)
    )


_BAD_ESCAPE = re.compile(r"%(?![0-9A-Fa-f]{2})")


def redirect(location: str, status: int = 303) -> HttpResponse:
    return HttpResponse(status, b"", "text/plain", {"Location": location})
