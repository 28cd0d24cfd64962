"""The seam between a COPYDATA target and its transports: what each may ask of the other.

A transport (tcp.py, udp.py, win32.py) moves one target's frames to its
receiver(s) and their replies back. It needs five things from the target's
side, and nothing else: its settings and frame layout, a bounded `Channel` per
receiver (opened when one connects, closed when it leaves), somewhere to say
the link's state, somewhere to hand the frames that come back, and the
target's log throttle for lines a peer can provoke at will. `TransportPort`
says exactly that; the `Emitter` implements it, and no transport imports the
emitter. The emitter only knows a transport as `Transport`.

Adding a transport: a class with `describe()` and `run()` that takes a
`TransportPort`, and a branch in `sink.make_transport`; see
docs/architecture.md (COPYDATA transport seam).
"""

from __future__ import annotations

from typing import Protocol

from gateway.codecs.copydata import Frame, Layout
from gateway.sinks.copydata.channel import Channel
from gateway.sinks.copydata.config import CopydataTarget
from gateway.sinks.copydata.throttle import LogThrottle


class TransportPort(Protocol):
    """What a transport needs from its target's emitter."""

    @property
    def name(self) -> str:
        """`<machine>/<target>`, for log lines and task names."""
        ...

    @property
    def target(self) -> CopydataTarget:
        """The target's settings: address, timeouts, backoff, limits."""
        ...

    @property
    def layout(self) -> Layout:
        """Field widths, encoding and max_cbdata, to decode what receivers send back."""
        ...

    @property
    def throttle(self) -> LogThrottle:
        """For log lines a peer can trigger at will (malformed frames, refused clients)."""
        ...

    def open_channel(self, peer: str) -> Channel:
        """A receiver is there: its own bounded queue of frames, starting with a snapshot."""
        ...

    def close_channel(self, channel: Channel) -> None:
        """The receiver is gone: stop filling its channel (its counts are kept)."""
        ...

    def set_state(self, state: str) -> None:
        """The link's state (`listening, 2 clients`, `connecting (connection refused)`) for the status."""
        ...

    async def on_frame(self, frame: Frame, peer: str) -> None:
        """A frame a receiver sent back (feedback, and writes when the target accepts them)."""
        ...


class Transport(Protocol):
    """Carries one target's frames to its receiver(s), and their replies back."""

    def describe(self) -> str:
        """Where it sends and how the link is, for Status/CopydataTargets."""
        ...

    async def run(self) -> None:
        """Serve until cancelled; never raises for a receiver's problem (logs, retries)."""
        ...
