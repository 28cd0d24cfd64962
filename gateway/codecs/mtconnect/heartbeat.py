"""SHDR heartbeats, both ends, as clocks the caller drives (times are monotonic seconds).

The agent (our MTConnect source) connects and sends `* PING`; an adapter that supports
heartbeats answers `* PONG <ms>`, its period. From then on the agent pings every period
and gives up when no PONG came for two periods. An adapter that never answers is kept
for `legacy_timeout` seconds of silence (any line counts), the reference agent's default
of 600 s. The adapter side (the simulator's SHDR face) answers every PING and gives up
after two periods without one.
"""

from __future__ import annotations

from enum import Enum

from gateway.codecs.mtconnect.shdr import PING, format_pong

LEGACY_TIMEOUT = 600.0


class Action(Enum):
    NONE = "none"
    SEND_PING = "send-ping"
    TIMED_OUT = "timed-out"


class AgentHeartbeat:
    """The connecting side: when to ping, and when the adapter is gone."""

    def __init__(self, now: float, *, legacy_timeout: float = LEGACY_TIMEOUT) -> None:
        self.legacy_timeout = legacy_timeout
        self.period: float | None = None  # seconds, once the adapter answered with a PONG
        self._last_pong = now
        self._last_data = now
        self._last_ping = now

    def opening(self) -> bytes:
        """The first bytes to send after connecting."""
        return PING

    def on_pong(self, heartbeat_ms: int | None, now: float) -> None:
        if heartbeat_ms is not None:
            self.period = heartbeat_ms / 1000.0
        self._last_pong = now
        self._last_data = now

    def on_data(self, now: float) -> None:
        self._last_data = now

    def poll(self, now: float) -> Action:
        """What to do at `now`; the caller sends PING for SEND_PING and closes for TIMED_OUT."""
        if self.period is None:
            return Action.TIMED_OUT if now - self._last_data >= self.legacy_timeout else Action.NONE
        if now - self._last_pong >= 2 * self.period:
            return Action.TIMED_OUT
        if now - self._last_ping >= self.period:
            self._last_ping = now
            return Action.SEND_PING
        return Action.NONE

    def next_deadline(self) -> float:
        """The next time `poll` may answer something other than NONE."""
        if self.period is None:
            return self._last_data + self.legacy_timeout
        return min(self._last_ping + self.period, self._last_pong + 2 * self.period)


class AdapterHeartbeat:
    """The adapter side: answer PINGs with our period; the agent is gone after two silent periods."""

    def __init__(self, *, heartbeat_ms: int = 10_000) -> None:
        self.pong = format_pong(heartbeat_ms)
        self.period = heartbeat_ms / 1000.0
        self._last_ping: float | None = None

    def on_ping(self, now: float) -> bytes:
        self._last_ping = now
        return self.pong

    def poll(self, now: float) -> Action:
        """TIMED_OUT once an agent that pinged has stopped for two periods (never before a first PING)."""
        if self._last_ping is not None and now - self._last_ping >= 2 * self.period:
            return Action.TIMED_OUT
        return Action.NONE
