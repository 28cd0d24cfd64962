"""SHDR, the MTConnect adapter protocol: a line reader (bytes in, events out) and a line writer.

SHDR is pipe-delimited text, one line per LF (CR-LF accepted):

    2024-05-01T12:00:00.123456Z|Xact|12.5|execution|ACTIVE   observations, several per line
    |Xact|12.6                                               no timestamp: the receive time
    2024-...Z@100.0|pcount|3                                 with a duration (seconds)
    2024-...Z|system|FAULT|E42:c1|2|HIGH|Laser overheated    condition: level|code[:id]|severity|qualifier|
                                                             text
    2024-...Z|message|CHG_INSRT|Change inserts               message: native code|text
    2024-...Z|current|10|100|1 2 3 4 5 6 7 8 9 10            time series: count|rate|values
    2024-...Z|description|"text with \\| a pipe"             a quoted field; \\ escapes | " and \\ inside
    2024-...Z|@ASSET@|T1.1|CuttingTool|<CuttingTool>...      assets (also --multiline--TAG bodies),
    2024-...Z|@REMOVE_ASSET@|T1.1                            also @REMOVE_ALL_ASSETS@|type,
                                                             @UPDATE_ASSET@|id|k|v...
    * shdrVersion: 2                                         protocol commands
    * PING / * PONG 10000                                    heartbeats (the adapter states its period in ms)

The number of fields after a key depends on the data item (a condition takes five), so
the reader asks `kind_of(key)`; by default every key is a plain value. Keys may carry
a device prefix (`device:key`), reported as `device`.

Like the reference agent, the reader never stops on bad input: a line it cannot read
(not UTF-8, too long, a bad timestamp, a condition with an unknown level, ...) becomes
a `Junk` event with the reason, is counted in `errors`, and reading goes on with the
next line. Memory is bounded by `max_line` (and `max_asset` for multi-line assets: a larger
one, or one with a line over `max_line`, is dropped with one Junk and its remaining lines are
skipped up to its terminator).

Where the reference agent is loose and this reader is not: a first field that is
neither empty nor a timestamp makes the line Junk (cppagent would silently use its clock
and shift every field); an unterminated quote is kept literally; whitespace inside quotes
is kept (cppagent trims the end).
"""

from __future__ import annotations

import hashlib
import math
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass
from datetime import datetime
from enum import Enum

from gateway.codecs.mtconnect.timestamps import format_timestamp, parse_timestamp

DEFAULT_MAX_LINE = 64 * 1024
DEFAULT_MAX_ASSET = 1 << 20
MULTILINE = "--multiline--"
CONDITION_LEVELS = frozenset({"NORMAL", "WARNING", "FAULT", "UNAVAILABLE"})


class ItemKind(Enum):
    """What the fields after a key mean; `fields` is how many there are."""

    VALUE = "value"  # value (also DATA_SET / TABLE text, kept raw)
    CONDITION = "condition"  # level | native code[:condition id] | native severity | qualifier | text
    MESSAGE = "message"  # native code | text
    ALARM = "alarm"  # code | native code | severity | state | text  (deprecated in MTConnect, still sent)
    TIME_SERIES = "time-series"  # count | rate | space-separated values

    @property
    def fields(self) -> int:
        return _FIELDS[self]


_FIELDS = {
    ItemKind.VALUE: 1,
    ItemKind.CONDITION: 5,
    ItemKind.MESSAGE: 2,
    ItemKind.ALARM: 5,
    ItemKind.TIME_SERIES: 3,
}


KindOf = Callable[[str], ItemKind]


def every_key_a_value(key: str) -> ItemKind:
    return ItemKind.VALUE


# --- events ----------------------------------------------------------------------------------


@dataclass(frozen=True, slots=True)
class Observation:
    timestamp: datetime
    key: str
    value: str  # the field as sent; "UNAVAILABLE" in any case is normalised to upper case
    device: str | None = None
    duration: float | None = None


@dataclass(frozen=True, slots=True)
class ConditionObservation:
    timestamp: datetime
    key: str
    level: str  # NORMAL, WARNING, FAULT or UNAVAILABLE
    native_code: str | None = None
    native_severity: str | None = None
    qualifier: str | None = None
    text: str = ""
    condition_id: str | None = None  # from `code:id`; the code alone is also the id
    device: str | None = None
    duration: float | None = None


@dataclass(frozen=True, slots=True)
class MessageObservation:
    timestamp: datetime
    key: str
    native_code: str | None
    text: str
    device: str | None = None
    duration: float | None = None


@dataclass(frozen=True, slots=True)
class AlarmObservation:
    timestamp: datetime
    key: str
    code: str
    native_code: str | None = None
    severity: str | None = None
    state: str | None = None
    text: str = ""
    device: str | None = None
    duration: float | None = None


@dataclass(frozen=True, slots=True)
class TimeSeriesObservation:
    timestamp: datetime
    key: str
    values: tuple[float, ...]  # empty when UNAVAILABLE
    rate: float | None = None
    device: str | None = None
    duration: float | None = None

    @property
    def unavailable(self) -> bool:
        return not self.values


@dataclass(frozen=True, slots=True)
class AssetChanged:
    timestamp: datetime
    asset_id: str
    asset_type: str
    body: str  # the asset's XML, unchecked (assets.make_asset checks it)


@dataclass(frozen=True, slots=True)
class AssetRemoved:
    timestamp: datetime
    asset_id: str


@dataclass(frozen=True, slots=True)
class AllAssetsRemoved:
    timestamp: datetime
    asset_type: str | None


@dataclass(frozen=True, slots=True)
class AssetUpdated:
    timestamp: datetime
    asset_id: str
    changes: tuple[tuple[str, str], ...]


@dataclass(frozen=True, slots=True)
class Command:
    """`* name: value`, e.g. shdrVersion, adapterVersion, device, uuid, serialNumber."""

    name: str
    value: str


@dataclass(frozen=True, slots=True)
class Ping:
    pass


@dataclass(frozen=True, slots=True)
class Pong:
    heartbeat_ms: int | None  # the adapter's period; None for a bare `* PONG`


@dataclass(frozen=True, slots=True)
class Junk:
    """A line (or one item of it) that was refused; `line` counts from 1."""

    line: int
    reason: str
    text: str  # the offending text, cut to 200 characters


Event = (
    Observation
    | ConditionObservation
    | MessageObservation
    | AlarmObservation
    | TimeSeriesObservation
    | AssetChanged
    | AssetRemoved
    | AllAssetsRemoved
    | AssetUpdated
    | Command
    | Ping
    | Pong
    | Junk
)


# --- fields ----------------------------------------------------------------------------------


def split_fields(line: str) -> list[str]:
    """Split one line into fields at unescaped pipes, as the reference agent's tokenizer does.

    Fields are trimmed of surrounding whitespace. A field that starts with `"` and whose
    closing `"` is followed by a pipe (or the end) is quoted: inside it, a backslash
    escapes the next character (`\\|`, `\\"`, `\\\\`). A trailing pipe ends in one empty field.
    """
    fields: list[str] = []
    i, n = 0, len(line)
    while i < n:
        while i < n and line[i].isspace():
            i += 1
        token: str | None = None
        if i < n and line[i] == '"':
            chars: list[str] = []
            j = i + 1
            while j < n:
                c = line[j]
                if c == "\\" and j + 1 < n:
                    chars.append(line[j + 1])
                    j += 2
                    continue
                if c == '"':
                    k = j + 1
                    while k < n and line[k].isspace():
                        k += 1
                    if k == n or line[k] == "|":
                        token, i = "".join(chars), k
                    break
                if c == "|":
                    break
                chars.append(c)
                j += 1
        if token is None:
            end = line.find("|", i)
            if end < 0:
                end = n
            token, i = line[i:end].rstrip(), end
        fields.append(token)
        if i < n and line[i] == "|":
            if i == n - 1:
                fields.append("")
            i += 1
    return fields


def quote_field(text: str) -> str:
    """`text` as one field the reader gives back unchanged. Raises ValueError for CR/LF."""
    if "\n" in text or "\r" in text:
        raise ValueError(f"an SHDR field cannot hold a line break: {text[:40]!r}")
    if "|" in text or text.startswith('"') or text != text.strip():
        escaped = text.replace("\\", "\\\\").replace('"', '\\"').replace("|", "\\|")
        return f'"{escaped}"'
    return text


# --- the reader ------------------------------------------------------------------------------


def _cut(text: str) -> str:
    return text if len(text) <= 200 else text[:197] + "..."


def _split_key(key: str) -> tuple[str | None, str]:
    device, sep, name = key.partition(":")
    return (device, name) if sep and device and name else (None, key)


def _opt(text: str) -> str | None:
    return text or None


@dataclass(slots=True)
class _PendingAsset:
    """A multi-line asset being collected; once `dropped`, its lines are skipped up to the terminator."""

    timestamp: datetime
    asset_id: str
    asset_type: str
    tag: str
    lines: list[str]
    size: int = 0
    dropped: bool = False


class ShdrReader:
    """Turns SHDR bytes, in any chunking, into events. Never raises on input.

    `feed(data, received_at)` returns the events of the complete lines; `received_at`
    stamps lines without a timestamp (the caller's clock, so the reader stays pure).
    """

    def __init__(
        self,
        kind_of: KindOf = every_key_a_value,
        *,
        max_line: int = DEFAULT_MAX_LINE,
        max_asset: int = DEFAULT_MAX_ASSET,
    ) -> None:
        self.kind_of = kind_of
        self.max_line = max_line
        self.max_asset = max_asset
        self.shdr_version = 2
        self.lines = 0  # complete lines read
        self.errors = 0  # Junk events produced
        self._buf = bytearray()
        self._discarding = False  # inside a line already refused as too long
        self._asset: _PendingAsset | None = None  # a multi-line asset being read

    @property
    def buffered(self) -> int:
        return len(self._buf)

    def feed(self, data: bytes, received_at: datetime) -> list[Event]:
        events: list[Event] = []
        buf = self._buf
        buf += data
        start = 0
        while True:
            end = buf.find(b"\n", start)
            if end < 0:
                break
            raw = bytes(buf[start:end])
            start = end + 1
            if self._discarding:
                self._discarding = False
                continue
            self.lines += 1
            if len(raw) > self.max_line:
                self._too_long(events, raw)
                continue
            self._line(raw, received_at, events)
        del buf[:start]
        if len(buf) > self.max_line:
            if not self._discarding:
                self.lines += 1
                self._too_long(events, bytes(buf))
            self._discarding = True
            buf.clear()
        return events

    def _too_long(self, events: list[Event], raw: bytes) -> None:
        self._junk(events, f"line longer than {self.max_line} bytes", raw[:200].decode("utf-8", "replace"))
        if (
            self._asset is not None and not self._asset.dropped
        ):  # a multi-line asset missing a line is no asset
            self._drop_asset(events, "one of its lines was too long")

    def feed_eof(self, received_at: datetime) -> list[Event]:
        """The connection closed: read a last line that had no LF; report an unfinished asset."""
        events: list[Event] = []
        if self._buf and not self._discarding:
            self.lines += 1
            self._line(bytes(self._buf), received_at, events)
        self._buf.clear()
        self._discarding = False
        if self._asset is not None:
            pending, self._asset = self._asset, None
            if not pending.dropped:
                self._junk(
                    events,
                    f"stream ended inside multi-line asset {pending.asset_id} (no {pending.tag})",
                    pending.asset_id,
                )
        return events

    def _junk(self, events: list[Event], reason: str, text: str) -> None:
        self.errors += 1
        events.append(Junk(self.lines, reason, _cut(text)))

    def _line(self, raw: bytes, received_at: datetime, events: list[Event]) -> None:
        if raw.endswith(b"\r"):
            raw = raw[:-1]
        try:
            line = raw.decode("utf-8")
        except UnicodeDecodeError as exc:
            self._junk(
                events, f"not UTF-8 ({exc.reason} at byte {exc.start})", raw.decode("utf-8", "replace")
            )
            return
        if self._asset is not None:
            self._asset_line(line, events)
            return
        if not line.strip():
            return
        if line.startswith("*"):
            self._command(line, events)
            return
        fields = split_fields(line)
        stamp, _, duration_text = fields[0].partition("@")
        timestamp: datetime | None
        if stamp.strip():
            timestamp = parse_timestamp(stamp.strip())
            if timestamp is None:
                self._junk(events, f"the first field {stamp[:40]!r} is not a timestamp (nor empty)", line)
                return
        else:
            timestamp = received_at
        duration: float | None = None
        if duration_text:
            try:
                duration = float(duration_text)
            except ValueError:
                duration = math.nan
            if not math.isfinite(duration) or duration < 0:
                self._junk(events, f"bad duration {duration_text[:40]!r} after the timestamp", line)
                return
        if len(fields) < 2 or (len(fields) == 2 and not fields[1]):
            self._junk(events, "no key|value after the timestamp", line)
            return
        self._items(fields, 1, timestamp, duration, line, events)

    def _items(
        self, fields: list[str], i: int, ts: datetime, duration: float | None, line: str, events: list[Event]
    ) -> None:
        n = len(fields)
        while i < n:
            key = fields[i]
            i += 1
            if not key:
                self._junk(events, f"empty key in field {i}", line)
                i += 1  # its value goes with it
                continue
            if key.startswith("@"):
                i = self._asset_command(key, fields, i, ts, line, events)
                continue
            device, name = _split_key(key)
            kind = self.kind_of(key)
            take = fields[i : i + kind.fields]
            i += kind.fields
            if not take:
                self._junk(events, f"key {key!r} has no value", line)
                continue
            take += [""] * (kind.fields - len(take))
            if kind is ItemKind.VALUE:
                value = take[0]
                events.append(
                    Observation(
                        ts, name, "UNAVAILABLE" if value.upper() == "UNAVAILABLE" else value, device, duration
                    )
                )
            elif kind is ItemKind.CONDITION:
                self._condition(ts, name, device, duration, take, line, events)
            elif kind is ItemKind.MESSAGE:
                events.append(MessageObservation(ts, name, _opt(take[0]), take[1], device, duration))
            elif kind is ItemKind.ALARM:
                code, native, severity, state, text = take
                events.append(
                    AlarmObservation(
                        ts, name, code, _opt(native), _opt(severity), _opt(state), text, device, duration
                    )
                )
            else:
                self._time_series(ts, name, device, duration, take, line, events)
            if self.shdr_version < 2 and kind.fields > 1:
                return  # SHDR 1: a multi-field item ends the line

    def _condition(
        self,
        ts: datetime,
        name: str,
        device: str | None,
        duration: float | None,
        take: list[str],
        line: str,
        events: list[Event],
    ) -> None:
        level, code, severity, qualifier, text = take
        level = level.upper()
        if level not in CONDITION_LEVELS:
            self._junk(
                events, f"condition {name!r}: level {take[0]!r} is not NORMAL/WARNING/FAULT/UNAVAILABLE", line
            )
            return
        native_code: str | None = code or None
        condition_id: str | None = native_code
        if code and ":" in code:
            before, _, after = code.partition(":")
            native_code, condition_id = before or None, after or before or None
        events.append(
            ConditionObservation(
                ts,
                name,
                level,
                native_code,
                _opt(severity),
                _opt(qualifier),
                text,
                condition_id,
                device,
                duration,
            )
        )

    def _time_series(
        self,
        ts: datetime,
        name: str,
        device: str | None,
        duration: float | None,
        take: list[str],
        line: str,
        events: list[Event],
    ) -> None:
        count_text, rate_text, values_text = take
        if count_text.upper() == "UNAVAILABLE" or values_text.upper() == "UNAVAILABLE":
            events.append(TimeSeriesObservation(ts, name, (), None, device, duration))
            return
        try:
            count = int(count_text)
            rate = float(rate_text) if rate_text else None
            values = tuple(float(v) for v in values_text.split())
        except ValueError:
            self._junk(events, f"time series {name!r}: count, rate and values must be numbers", line)
            return
        if count != len(values):
            self._junk(events, f"time series {name!r}: count {count} but {len(values)} values", line)
            return
        events.append(TimeSeriesObservation(ts, name, values, rate, device, duration))

    def _asset_command(
        self, key: str, fields: list[str], i: int, ts: datetime, line: str, events: list[Event]
    ) -> int:
        n = len(fields)
        if key == "@ASSET@":
            if n - i < 3:
                self._junk(events, "@ASSET@ needs an asset id, a type and a body", line)
                return n
            asset_id, asset_type, body = fields[i : i + 3]
            if not asset_id or not asset_type:
                self._junk(events, "@ASSET@ needs an asset id and a type", line)
                return i + 3
            if body.startswith(MULTILINE):
                self._asset = _PendingAsset(ts, asset_id, asset_type, body, [])
                return n  # the rest of the line is the terminator tag
            events.append(AssetChanged(ts, asset_id, asset_type, body))
            return i + 3
        if key == "@REMOVE_ASSET@":
            if i >= n or not fields[i]:
                self._junk(events, "@REMOVE_ASSET@ needs an asset id", line)
                return i + 1
            events.append(AssetRemoved(ts, fields[i]))
            return i + 1
        if key == "@REMOVE_ALL_ASSETS@":
            events.append(AllAssetsRemoved(ts, _opt(fields[i]) if i < n else None))
            return i + 1
        if key == "@UPDATE_ASSET@":
            rest = fields[i:]
            if not rest or not rest[0] or len(rest) % 2 == 0:
                self._junk(events, "@UPDATE_ASSET@ needs an asset id and property|value pairs", line)
                return n
            pairs = tuple((rest[k], rest[k + 1]) for k in range(1, len(rest), 2))
            events.append(AssetUpdated(ts, rest[0], pairs))
            return n
        self._junk(events, f"unknown asset command {key!r}", line)
        return n

    def _asset_line(self, line: str, events: list[Event]) -> None:
        pending = self._asset
        assert pending is not None
        if line.startswith(pending.tag):
            self._asset = None
            if not pending.dropped:
                events.append(
                    AssetChanged(
                        pending.timestamp, pending.asset_id, pending.asset_type, "\n".join(pending.lines)
                    )
                )
            return
        if pending.dropped:
            return
        pending.size += len(line) + 1
        if pending.size > self.max_asset:
            self._drop_asset(events, f"it is larger than {self.max_asset} bytes")
            return
        pending.lines.append(line)

    def _drop_asset(self, events: list[Event], why: str) -> None:
        """Refuse the multi-line asset being read; its remaining lines are skipped up to its terminator."""
        pending = self._asset
        assert pending is not None
        pending.dropped = True
        pending.lines = []
        self._junk(events, f"multi-line asset {pending.asset_id} dropped: {why}", pending.asset_id)

    def _command(self, line: str, events: list[Event]) -> None:
        text = line[1:].strip()
        word = text.split(None, 1)
        if word and word[0] == "PING" and len(word) == 1:
            events.append(Ping())
            return
        if word and word[0] == "PONG":
            if len(word) == 1:
                events.append(Pong(None))
                return
            try:
                period = int(word[1])
            except ValueError:
                period = -1
            if period <= 0:
                self._junk(events, f"* PONG needs a period in milliseconds, not {word[1][:40]!r}", line)
                return
            events.append(Pong(period))
            return
        name, sep, value = text.partition(":")
        if not sep or not name.strip() or " " in name.strip():
            self._junk(events, "a protocol command is `* name: value`, `* PING` or `* PONG <ms>`", line)
            return
        name, value = name.strip(), value.strip()
        if name == "shdrVersion":
            try:
                self.shdr_version = int(float(value))
            except ValueError:
                self._junk(events, f"* shdrVersion needs a number, not {value[:40]!r}", line)
                return
        events.append(Command(name, value))


# --- the writer ------------------------------------------------------------------------------


def _check_key(key: str) -> str:
    if not key or "|" in key or any(c.isspace() for c in key) or key[0] in "*@":
        raise ValueError(f"{key!r} is not an SHDR key (non-empty, no pipe or white space, not * or @ first)")
    return key


def _head(timestamp: datetime | None, duration: float | None = None) -> str:
    text = format_timestamp(timestamp) if timestamp is not None else ""
    if duration is not None:
        if not math.isfinite(duration) or duration < 0:
            raise ValueError(f"a duration is a non-negative number of seconds, not {duration!r}")
        text += f"@{duration!r}"
    return text


def _key(key: str, device: str | None) -> str:
    return _check_key(f"{device}:{key}" if device else key)


def format_pairs(
    timestamp: datetime | None, pairs: Iterable[tuple[str, str]], duration: float | None = None
) -> bytes:
    """One line of key|value pairs; timestamp None leaves the field empty (the receiver's clock)."""
    parts = [_head(timestamp, duration)]
    for key, value in pairs:
        parts.append(_check_key(key))
        parts.append(quote_field(value))
    if len(parts) < 3:
        raise ValueError("an SHDR data line needs at least one key|value pair")
    return ("|".join(parts) + "\n").encode("utf-8")


def format_condition(
    timestamp: datetime | None,
    key: str,
    level: str,
    native_code: str | None = None,
    native_severity: str | None = None,
    qualifier: str | None = None,
    text: str = "",
    condition_id: str | None = None,
) -> bytes:
    if level.upper() not in CONDITION_LEVELS:
        raise ValueError(f"condition level must be one of {sorted(CONDITION_LEVELS)}, not {level!r}")
    if native_code is not None and ":" in native_code:
        raise ValueError(f"a native code cannot contain ':' (it separates the condition id): {native_code!r}")
    code = native_code or ""
    if condition_id is not None and condition_id != native_code:
        code = f"{code}:{condition_id}"
    fields = [
        _head(timestamp),
        _check_key(key),
        level.upper(),
        code,
        native_severity or "",
        qualifier or "",
        text,
    ]
    return ("|".join(quote_field(f) if n > 1 else f for n, f in enumerate(fields)) + "\n").encode("utf-8")


def format_time_series(
    timestamp: datetime | None, key: str, values: Sequence[float], rate: float | None = None
) -> bytes:
    numbers = " ".join(repr(float(v)) for v in values)
    rate_text = repr(float(rate)) if rate is not None else ""
    return f"{_head(timestamp)}|{_check_key(key)}|{len(values)}|{rate_text}|{numbers}\n".encode()


def format_asset(timestamp: datetime | None, asset_id: str, asset_type: str, body: str) -> bytes:
    """An @ASSET@ line; a body with line breaks goes multi-line, with a terminator it cannot contain."""
    head = f"{_head(timestamp)}|@ASSET@|{quote_field(asset_id)}|{quote_field(asset_type)}|"
    if "\n" not in body and "\r" not in body:
        return (head + quote_field(body) + "\n").encode("utf-8")
    digest = hashlib.sha1(body.encode("utf-8", "surrogatepass")).hexdigest()
    tag = MULTILINE + digest[:12]
    lines = body.replace("\r\n", "\n").replace("\r", "\n").split("\n")
    if any(line.startswith(tag) for line in lines):
        raise ValueError("the asset body contains its own multi-line terminator")
    return (head + tag + "\n" + "\n".join(lines) + "\n" + tag + "\n").encode("utf-8")


def format_command(name: str, value: str) -> bytes:
    if not name or any(c in name for c in ": \r\n"):
        raise ValueError(f"{name!r} is not an SHDR command name")
    quote_field(value)  # refuses line breaks
    return f"* {name}: {value}\n".encode()


PING = b"* PING\n"


def format_pong(heartbeat_ms: int) -> bytes:
    if heartbeat_ms <= 0:
        raise ValueError("the heartbeat period must be positive")
    return f"* PONG {heartbeat_ms}\n".encode()


def encode(event: Event) -> bytes:
    """One line (or multi-line asset) for an event the reader produces; Junk cannot be encoded."""
    if isinstance(event, Observation):
        return format_pairs(event.timestamp, [(_key(event.key, event.device), event.value)], event.duration)
    if isinstance(event, ConditionObservation):
        return format_condition(
            event.timestamp,
            _key(event.key, event.device),
            event.level,
            event.native_code,
            event.native_severity,
            event.qualifier,
            event.text,
            event.condition_id,
        )
    if isinstance(event, MessageObservation):
        fields = [_head(event.timestamp), _key(event.key, event.device), event.native_code or "", event.text]
        return ("|".join(quote_field(f) if n > 1 else f for n, f in enumerate(fields)) + "\n").encode("utf-8")
    if isinstance(event, AlarmObservation):
        fields = [
            _head(event.timestamp),
            _key(event.key, event.device),
            event.code,
            event.native_code or "",
            event.severity or "",
            event.state or "",
            event.text,
        ]
        return ("|".join(quote_field(f) if n > 1 else f for n, f in enumerate(fields)) + "\n").encode("utf-8")
    if isinstance(event, TimeSeriesObservation):
        if event.unavailable:
            return (
                format_pairs(event.timestamp, [(_key(event.key, event.device), "UNAVAILABLE")])[:-1] + b"||\n"
            )
        return format_time_series(event.timestamp, _key(event.key, event.device), event.values, event.rate)
    if isinstance(event, AssetChanged):
        return format_asset(event.timestamp, event.asset_id, event.asset_type, event.body)
    if isinstance(event, AssetRemoved):
        return f"{_head(event.timestamp)}|@REMOVE_ASSET@|{quote_field(event.asset_id)}\n".encode()
    if isinstance(event, AllAssetsRemoved):
        return (
            f"{_head(event.timestamp)}|@REMOVE_ALL_ASSETS@|{quote_field(event.asset_type or '')}\n".encode()
        )
    if isinstance(event, AssetUpdated):
        pairs = "|".join(f"{quote_field(k)}|{quote_field(v)}" for k, v in event.changes)
        return f"{_head(event.timestamp)}|@UPDATE_ASSET@|{quote_field(event.asset_id)}|{pairs}\n".encode()
    if isinstance(event, Command):
        return format_command(event.name, event.value)
    if isinstance(event, Ping):
        return PING
    if isinstance(event, Pong):
        return b"* PONG\n" if event.heartbeat_ms is None else format_pong(event.heartbeat_ms)
    raise ValueError("a Junk event has no SHDR form")
