"""The two counters of a Sparkplug edge node: `seq` per message and `bdSeq` per MQTT session.

seq (Sparkplug 3.0, 6.4.1 and 4.x): NBIRTH carries 0; every later message of the edge node,
node-level or device-level (DBIRTH, NDATA, DDATA, DDEATH), one more, 255 wrapping to 0. NDEATH
carries none.

bdSeq (5.x, edge node session establishment): the will (NDEATH) of every MQTT CONNECT carries one
more than the previous CONNECT's, starting at 0, 255 wrapping to 0; the NBIRTHs of that session,
rebirths included, repeat it, so that a host matches an NDEATH to its NBIRTH.

Where the specification is silent: bdSeq restarts at 0 with the process unless the sink passes
the last value it persisted (`BdSeq(last=…)`), so that a restart still gives a new number.
"""

from __future__ import annotations

MODULUS = 256


class Seq:
    """The edge node's message sequence number, 0-255."""

    __slots__ = ("_next",)

    def __init__(self) -> None:
        self._next = 0

    def birth(self) -> int:
        """The NBIRTH's number: 0, and the count restarts after it."""
        self._next = 1
        return 0

    def next(self) -> int:
        """The number of the next DBIRTH, NDATA, DDATA or DDEATH."""
        value = self._next
        self._next = (value + 1) % MODULUS
        return value

    @property
    def peek(self) -> int:
        """The number the next message will carry (for logs and tests)."""
        return self._next


class BdSeq:
    """The birth/death sequence number: one per MQTT CONNECT, 0-255."""

    __slots__ = ("_current",)

    def __init__(self, *, last: int | None = None) -> None:
        if last is not None and not 0 <= last < MODULUS:
            raise ValueError(f"bdSeq is 0..{MODULUS - 1}, got {last}")
        self._current = last

    def connect(self) -> int:
        """The number for a new CONNECT's will (and that session's NBIRTHs)."""
        self._current = 0 if self._current is None else (self._current + 1) % MODULUS
        return self._current

    @property
    def current(self) -> int:
        """The number of the session under way; ValueError before the first connect()."""
        if self._current is None:
            raise ValueError("no CONNECT yet: call connect() for the will first")
        return self._current
