"""A primary host application's STATE, and whether it is online for this edge node.

Sparkplug 3.0 (4.x "STATE"): the payload is UTF-8 JSON `{"online": true|false, "timestamp": <ms>}`
on `spBv1.0/STATE/<host_id>`, retained, QoS 1. Sparkplug 2.2 hosts publish the plain text
`ONLINE` or `OFFLINE` on `STATE/<host_id>`; `parse_state` reads both (by content, whatever the
topic), the old form marked `legacy` and without a timestamp.

`PrimaryHost` applies the edge node's rules (5.x): an online STATE counts only if its timestamp is
not older than the last online one seen; an offline STATE counts only if it is not older than
the last online one (an older offline is the will of a session the host has already replaced).
A legacy STATE, having no timestamp, always counts.

Choices where the specification is silent: other keys beside `online` and `timestamp` are
ignored (a later version may add some); the legacy text is read case-sensitively after
trimming white space, as 2.2 prints it; a payload over 64 KiB is refused unread.
"""

from __future__ import annotations

import json
from dataclasses import dataclass

from gateway.codecs.sparkplug.errors import BadState

MAX_STATE = 64 * 1024
_UINT64 = 1 << 64


@dataclass(frozen=True, slots=True)
class HostState:
    online: bool
    timestamp: int | None  # ms since 1970 UTC; None for a legacy (2.2) STATE
    legacy: bool = False


def parse_state(payload: bytes) -> HostState:
    """Read a STATE payload; BadState with the reason if it is neither form."""
    if len(payload) > MAX_STATE:
        raise BadState(f"{len(payload)} bytes is more than a STATE payload needs ({MAX_STATE})")
    try:
        text = bytes(payload).decode("utf-8")
    except UnicodeDecodeError as exc:
        raise BadState(f"the payload is not UTF-8 text (byte {exc.start})") from None
    stripped = text.strip()
    if stripped in ("ONLINE", "OFFLINE"):
        return HostState(online=stripped == "ONLINE", timestamp=None, legacy=True)
    if not stripped.startswith("{"):
        raise BadState(f'expected {{"online": …, "timestamp": …}} or ONLINE/OFFLINE, got {stripped[:40]!r}')
    try:
        document = json.loads(stripped)
    except (ValueError, RecursionError) as exc:
        raise BadState(f"malformed JSON: {str(exc)[:80]}") from None
    if not isinstance(document, dict):  # pragma: no cover - text starting with { is an object
        raise BadState("the JSON is not an object")
    online = document.get("online")
    if not isinstance(online, bool):
        raise BadState(f'"online" must be true or false, got {_shown(online)}')
    timestamp = document.get("timestamp")
    if isinstance(timestamp, float) and timestamp.is_integer():
        timestamp = int(timestamp)
    if isinstance(timestamp, bool) or not isinstance(timestamp, int) or not 0 <= timestamp < _UINT64:
        raise BadState(f'"timestamp" must be ms since 1970 (an unsigned integer), got {_shown(timestamp)}')
    return HostState(online=online, timestamp=timestamp)


def _shown(value: object) -> str:
    if value is None:
        return "nothing"
    return json.dumps(value)[:40]


class PrimaryHost:
    """Whether the configured primary host is online, from the STATE messages seen so far."""

    __slots__ = ("_last_online_ts", "online")

    def __init__(self) -> None:
        self.online = False
        self._last_online_ts: int | None = None

    def feed(self, state: HostState) -> bool:
        """Take one STATE message; True if it changed `online`. Stale messages change nothing."""
        last = self._last_online_ts
        if state.timestamp is not None and last is not None and state.timestamp < last:
            return False
        if state.online and state.timestamp is not None:
            self._last_online_ts = state.timestamp
        changed = state.online != self.online
        self.online = state.online
        return changed

    def reset(self) -> None:
        """Forget what was seen (a new MQTT session: the retained STATE comes again)."""
        self.online = False
        self._last_online_ts = None
