"""The drip-feeds of one gateway, fed by one scheduler: which line sends next, and how much.

The network-DNC patent's idea (issue 14): each transmission sized by the run
time of the blocks it carries, and the machine that will run dry first served
first. `DripScheduler` (gateway/codecs/dnc/schedule.py) decides that, purely;
this is its place among the transfers, which the lines' one I/O thread steps
(lineio.py, `DripFleet.io`).

A line that drip-feeds joins the fleet and sends only what it was granted. A
line that wants more asks the scheduler, which hands out whatever can be granted
now to whichever lines it goes to; a line granted something by another's step
is told through `on_grant` and stepped at once. The controller stays the
authority: its DC3 pauses the line in the model, its DC1 puts the model right and
teaches it the machine's real pace. A line whose controller does flow control is
never held back when nothing else wants its link (work-conserving); lines that
name the same `link` (a device server, an uplink) share its `link_capacity`,
the most urgent first.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable, Iterable, Sequence

from gateway.codecs.dnc import BlockCost, DripLine, DripScheduler
from gateway.transports.dnc.config import ControllerSerial
from gateway.transports.dnc.lineio import LineLoop

NO_GRANT_WAIT = 0.05  # s a line with nothing granted waits at most before it asks again
MIN_GRANT_WAIT = 0.0005  # s: the soonest it asks again


class FleetLine:
    """One line's part in the fleet, used from the lines' I/O thread."""

    def __init__(self, fleet: DripFleet, key: str) -> None:
        self.fleet = fleet
        self.key = key
        self.budget = 0  # bytes granted and not yet written (under the fleet's lock)
        #: Called (on the I/O thread) when another line's step granted this one something.
        self.on_grant: Callable[[], None] = lambda: None
        self.closed = False

    def allowance(self) -> int:
        """Bytes this line may write now, asking the scheduler when nothing is left of its grants."""
        if self.budget <= 0:
            self.fleet.hand_out(self)
        return self.budget

    def wrote(self, count: int) -> None:
        with self.fleet.lock:
            self.budget = max(0, self.budget - count)

    def wait_seconds(self) -> float:
        """How long to wait for a grant before asking again: until this line may be served (a grant another
        line's step made for it ends it sooner, through `on_grant`)."""
        return self.fleet.wait_seconds(self.key)

    def started(self) -> None:
        """The controller takes the program now (its first DC1, or at once): its machine cuts."""
        with self.fleet.lock:
            self.fleet.scheduler.start(self.key, time.monotonic())

    def held(self, held: bool, written: int) -> None:
        """A DC3 (True) or the DC1 after it (False), after `written` bytes."""
        with self.fleet.lock:
            now = time.monotonic()
            if held:
                self.fleet.scheduler.dc3(self.key, now, written)
            else:
                self.fleet.scheduler.dc1(self.key, now, written)
        if not held:
            self.fleet.hand_out(self)

    def lead(self) -> float:
        """Seconds of cutting the scheduler's model says the controller holds."""
        with self.fleet.lock:
            return self.fleet.scheduler.ahead(self.key, time.monotonic())

    def speed(self) -> float:
        """The machine's pace over its estimate, as learned from its DC1s."""
        with self.fleet.lock:
            return self.fleet.scheduler.speed(self.key)

    def close(self) -> None:
        if self.closed:
            return
        self.closed = True
        self.fleet.leave(self)


class DripFleet:
    """One scheduler for every drip-feed of a gateway, and the one I/O thread that serves its lines."""

    def __init__(
        self, *, lead_time: float = 30.0, links: dict[str, float] | None = None, max_chunk: int = 200
    ) -> None:
        self.lock = threading.Lock()
        self.scheduler = DripScheduler(lead_time=lead_time, links=links, max_chunk=max_chunk)
        self.links = dict(links or {})
        self.io = LineLoop()
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
        flow_control: bool = True,
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
                    flow_control=flow_control,
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
        """Grant what can be granted now, to whichever lines it goes to, and tell them."""
        granted: list[FleetLine] = []
        with self.lock:
            now = time.monotonic()
            while (grant := self.scheduler.next_grant(now)) is not None:
                member = self._members.get(grant.key)
                if member is None:
                    continue
                member.budget += grant.size
                if member is not asking:
                    granted.append(member)
        for member in granted:
            member.on_grant()

    def wait_seconds(self, key: str) -> float:
        with self.lock:
            now = time.monotonic()
            when = self.scheduler.wake_at(now, key)
        if when is None:
            return NO_GRANT_WAIT
        return min(NO_GRANT_WAIT, max(MIN_GRANT_WAIT, when - now))
