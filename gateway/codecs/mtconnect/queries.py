"""MTConnect REST requests: a request target (`/dev/sample?from=5&count=10`) into a checked request.

What this module refuses, it refuses as the agent must answer (RequestError with a 2.4
error code): an unknown request is INVALID_URI; a parameter that is unknown, repeated,
not a number, or not allowed with another is INVALID_REQUEST; a negative interval or a
heartbeat of 0 is OUT_OF_RANGE. What needs the agent's state is checked where that
state is: the device (`resolve_device`, NO_DEVICE), the path (`paths`, INVALID_PATH),
sequence numbers and counts (`buffer`, OUT_OF_RANGE).
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from urllib.parse import parse_qsl, unquote

from gateway.codecs.mtconnect.errors import ErrorCode, OutOfRange, RequestError
from gateway.codecs.mtconnect.model import Catalog, Device
from gateway.codecs.mtconnect.paths import PathIndex, parse_path

MAX_TARGET = 8192
MAX_PARAMETERS = 16
DEFAULT_COUNT = 100
DEFAULT_HEARTBEAT_MS = 10_000
_INTEGER = re.compile(r"[+-]?[0-9]{1,20}\Z")
_COMMON = frozenset({"format", "pretty", "deviceType"})
_ALLOWED = {
    "probe": _COMMON,
    "current": _COMMON | {"path", "at", "interval", "heartbeat"},
    "sample": _COMMON | {"path", "from", "to", "count", "interval", "heartbeat"},
    "assets": _COMMON | {"type", "removed", "count", "device"},
}


@dataclass(frozen=True, slots=True)
class Request:
    """One checked request; only the fields of its `kind` are set."""

    kind: str  # probe, current, sample, assets
    device: str | None = None  # as named in the URI or `device=`: resolve with resolve_device
    format: str = "xml"  # xml or json
    pretty: bool = False
    path: str | None = None
    at: int | None = None
    from_: int | None = None
    to: int | None = None
    count: int = DEFAULT_COUNT
    interval: int | None = None  # ms; streaming
    heartbeat: int = DEFAULT_HEARTBEAT_MS  # ms, while streaming
    asset_ids: tuple[str, ...] = ()
    asset_type: str | None = None
    removed: bool = False


def _invalid(message: str) -> RequestError:
    return RequestError(ErrorCode.INVALID_REQUEST, message)


def _integer(name: str, text: str, *, minimum: int, maximum: int) -> int:
    if not _INTEGER.match(text):
        raise _invalid(f"'{name}' must be an integer, not {text[:40]!r}")
    value = int(text)
    if not minimum <= value <= maximum:
        raise OutOfRange(name, value, minimum, maximum, f"'{name}' must be in [{minimum}, {maximum}]")
    return value


def _boolean(name: str, text: str) -> bool:
    lowered = text.lower()
    if lowered in ("true", "1", "yes"):
        return True
    if lowered in ("false", "0", "no", ""):
        return False
    raise _invalid(f"'{name}' must be true or false, not {text[:40]!r}")


def parse_request(target: str) -> Request:
    """Check a request target (path and query, already without scheme and host). Raises RequestError."""
    if len(target) > MAX_TARGET:
        raise RequestError(ErrorCode.INVALID_URI, f"the request is longer than {MAX_TARGET} characters")
    path_part, _, query = target.partition("?")
    try:
        segments = [unquote(s, errors="strict") for s in path_part.split("/") if s]
    except UnicodeDecodeError:
        raise RequestError(ErrorCode.INVALID_URI, "the request path is not UTF-8") from None
    kind, device, asset_ids = _route(segments, path_part)
    params = _parameters(query, kind)
    fmt = params.get("format", "xml").lower()
    if fmt not in ("xml", "json"):
        raise _invalid(f"'format' must be xml or json, not {params['format'][:40]!r}")
    path = params.get("path")
    if path is not None and not path.strip():
        raise _invalid("'path' is empty")
    if "at" in params and "interval" in params:
        raise _invalid("'at' and 'interval' cannot be used together")
    if "device" in params:
        if device is not None:
            raise _invalid("the device is named twice (in the path and in 'device')")
        device = params["device"]

    def number(name: str, minimum: int, maximum: int) -> int | None:
        text = params.get(name)
        return None if text is None else _integer(name, text, minimum=minimum, maximum=maximum)

    sequence_max = 2**64 - 1
    count = number("count", -(2**31), 2**31 - 1)
    heartbeat = number("heartbeat", 1, 2**31 - 1)
    return Request(
        kind=kind,
        device=device,
        format=fmt,
        pretty=_boolean("pretty", params.get("pretty", "false")),
        path=path,
        at=number("at", 0, sequence_max),
        from_=number("from", 0, sequence_max),
        to=number("to", 0, sequence_max),
        count=DEFAULT_COUNT if count is None else count,
        interval=number("interval", 0, 2**31 - 1),
        heartbeat=DEFAULT_HEARTBEAT_MS if heartbeat is None else heartbeat,
        asset_ids=asset_ids,
        asset_type=params.get("type"),
        removed=_boolean("removed", params.get("removed", "false")),
    )


def _route(segments: list[str], raw: str) -> tuple[str, str | None, tuple[str, ...]]:
    if not raw.startswith("/"):
        raise RequestError(ErrorCode.INVALID_URI, "the request path must start with /")
    words = ("probe", "current", "sample", "asset", "assets")
    if not segments:
        return "probe", None, ()
    head = segments[0]
    if head in ("asset", "assets"):
        if len(segments) > 2:
            raise RequestError(ErrorCode.INVALID_URI, f"unknown request {raw[:80]!r}")
        ids = tuple(i for i in segments[1].split(";") if i) if len(segments) == 2 else ()
        return "assets", None, ids
    if head in words:
        if len(segments) > 1:
            raise RequestError(ErrorCode.INVALID_URI, f"unknown request {raw[:80]!r}")
        return head, None, ()
    if len(segments) == 1:
        return "probe", head, ()
    if len(segments) == 2 and segments[1] in words:
        kind = "assets" if segments[1] in ("asset", "assets") else segments[1]
        return kind, head, ()
    raise RequestError(ErrorCode.INVALID_URI, f"unknown request {raw[:80]!r}")


def _parameters(query: str, kind: str) -> dict[str, str]:
    if not query:
        return {}
    try:
        pairs = parse_qsl(query, keep_blank_values=True, errors="strict", max_num_fields=MAX_PARAMETERS)
    except UnicodeDecodeError:
        raise _invalid("the query is not UTF-8") from None
    except ValueError:
        raise _invalid(f"more than {MAX_PARAMETERS} query parameters") from None
    params: dict[str, str] = {}
    allowed = _ALLOWED[kind]
    for name, value in pairs:
        if name not in allowed:
            raise _invalid(
                f"'{name[:40]}' is not a parameter of {kind} (allowed: {', '.join(sorted(allowed))})"
            )
        if name in params:
            raise _invalid(f"'{name}' is given twice")
        params[name] = value
    return params


def resolve_device(catalog: Catalog, name: str | None) -> Device | None:
    """The device a request names (by name or uuid), None for all; raises NO_DEVICE."""
    if name is None:
        return None
    device = catalog.device(name)
    if device is None:
        raise RequestError(ErrorCode.NO_DEVICE, f"no device named {name[:80]!r}")
    return device


def select_items(request: Request, catalog: Catalog, index: PathIndex) -> frozenset[str] | None:
    """The data item ids a /current or /sample covers: its device's, narrowed by its path; None for all.

    Raises NO_DEVICE or INVALID_PATH. (Cache the answer per (device, path): paths repeat.)
    """
    device = resolve_device(catalog, request.device)
    if request.path is not None:
        return index.select(parse_path(request.path), device)
    if device is not None:
        return catalog.device_items(device)
    return None
