"""The drip-feeds of one gateway, fed by one scheduler: which line sends next, and how much.

The network-DNC patent's idea (issue 14): every line's controller should hold
`lead_time` seconds of cutting ahead, each transmission sized by the run time of
the blocks it carries, and the machine that will run dry first served first.
`DripScheduler` (gateway/codecs/dnc/schedule.py) decides that, purely; this is
its place among the line threads (transfer.py, one thread per line).

A line that drip-feeds joins the fleet and sends only what it was granted. Any
line's thread that wants more asks the scheduler under the fleet's lock, hands
every grant it makes to the line it is for, and wakes that line's thread through
a pipe its wait selects on beside the port. The controller stays the authority:
its DC3 pauses the line in the model, its DC1 resynchronises the model (the
controller is down to its low level). Lines that name the same `link` (a device
server, an uplink) share its `link_capacity` by the same rule.
"""

from __future__ import annotations

import contextlib
import os
import threading
import time
from collections.abc import Iterable, Sequence

from gateway.codecs.dnc import BlockCost, DripLine, DripScheduler
from gateway.config.jobs import ControllerSerial

NO_GRANT_WAIT = 0.05  # s a line with nothing granted waits at most before it asks again


class FleetLine:
    """One line's part in the fleet, used from that line's thread."""

    def __init__(self, fleet: DripFleet, key: str) -> None:
        self.fleet = fleet
        self.key = key
        self.budget = 0  # bytes granted and not yet written (under the fleet's lock)
        self._read, self._write = os.pipe()
        os.set_blocking(self._read, False)
        os.set_blocking(self._write, False)
        self.closed = False

    @property
    def wake_fd(self) -> int:
        """Readable when a grant came for this line from another line's thread."""
        return self._read

    def wake(self) -> None:
        with contextlib.suppress(BlockingIOError, OSError):  # a full pipe is awake already
            os.write(self._write, b".")

    def drain(self) -> None:
        with contextlib.suppress(BlockingIOError, OSError):
            while os.read(self._read, 64):
                pass

    def allowance(self) -> int:
        """Bytes this line may write now, asking the scheduler when nothing is left of its grants."""
        if self.budget <= 0:
            self.fleet.hand_out(self)
        return self.budget

    def wrote(self, count: int) -> None:
        with self.fleet.lock:
            self.budget = max(0, self.budget - count)

    def wait_seconds(self) -> float:
        """How long to wait for a grant before asking again: until this line may be served (a wake through
        the pipe, a grant another line's thread made for it, ends it sooner). Only the lines that may be
        served then wake, not all of them each time the shared link is free."""
        return self.fleet.wait_seconds(self.key)

    def started(self) -> None:
        """The controller takes the program now (its first DC1, or at once): its machine cuts."""
        with self.fleet.lock:
            self.fleet.scheduler.start(self.key, time.monotonic())

    def held(self, held: bool) -> None:
        """A DC3 (True) or the DC1 after it (False)."""
        with self.fleet.lock:
            now = time.monotonic()
            self.fleet.scheduler.set_paused(self.key, held)
            if not held:
                self.fleet.scheduler.resync(self.key, now, 0)
        if not held:
            self.fleet.hand_out(self)

    def lead(self) -> float:
        """Seconds of cutting the scheduler's model says the controller holds."""
        with self.fleet.lock:
            return self.fleet.scheduler.ahead(self.key, time.monotonic())

    def close(self) -> None:
        if self.closed:
            return
        self.closed = True
        self.fleet.leave(self)
        for fd in (self._read, self._write):
            with contextlib.suppress(OSError):
                os.close(fd)


class DripFleet:
    """One scheduler for every drip-feed of a gateway (a process's lines), thread-safe."""

    def __init__(
        self, *, lead_time: float = 30.0, links: dict[str, float] | None = None, max_chunk: int = 200
    ) -> None:
        self.lock = threading.Lock()
        self.scheduler = DripScheduler(lead_time=lead_time, links=links, max_chunk=max_chunk)
        self.links = dict(links or {})
        self._members: dict[str, FleetLine] = {}
        self._serial = 0

    @classmethod
    def for_lines(cls, lines: Iterable[tuple[str, ControllerSerial]]) -> DripFleet:
        """The fleet of these machines' lines and their shared links (the loader checked that lines naming
        the same link agree on its capacity; the first one counts)."""
        capacities: dict[str, float] = {}
        chunk = 1
        for _machine, settings in lines:
            chunk = max(chunk, settings.chunk_size)
            if settings.link is not None and settings.link_capacity is not None:
                capacities.setdefault(settings.link, settings.link_capacity)
        return cls(links=capacities, max_chunk=max(200, chunk))

    def join(
        self,
        name: str,
        *,
        rate: float,
        buffer_size: int,
        blocks: Sequence[BlockCost],
        link: str | None,
        lead_time: float,
    ) -> FleetLine:
        """A drip-feed of `blocks` on line `name` takes part. Raises ValueError when it cannot be
        drip-fed (a block longer than the controller's buffer)."""
        with self.lock:
            self._serial += 1
            key = f"{name}#{self._serial}"
            self.scheduler.add(
                DripLine(
                    key,
                    rate,
                    buffer_size,
                    blocks,
                    link=link if link in self.links else None,
                    lead_time=lead_time,
                )
            )
            member = FleetLine(self, key)
            self._members[key] = member
            return member

    def leave(self, member: FleetLine) -> None:
        with self.lock:
            self.scheduler.remove(member.key)
            self._members.pop(member.key, None)

    def hand_out(self, asking: FleetLine) -> None:
        """Grant what can be granted now, to whichever lines it goes to, and wake them."""
        woken: list[FleetLine] = []
        with self.lock:
            now = time.monotonic()
            while (grant := self.scheduler.next_grant(now)) is not None:
                member = self._members.get(grant.key)
                if member is None:
                    continue
                member.budget += grant.size
                if member is not asking:
                    woken.append(member)
        for member in woken:
            member.wake()

    def wait_seconds(self, key: str) -> float:
        with self.lock:
            now = time.monotonic()
            when = self.scheduler.wake_at(now, key)
        if when is None:
            return NO_GRANT_WAIT
        return min(NO_GRANT_WAIT, max(0.0005, when - now))
