"""Reconnecting to something that comes and goes: the delays between attempts, and what the log says.

Every link the gateway keeps (a controller, the MQTT broker, a COPYDATA
receiver, a port to bind) retries the same way, and drivers still to come
(MTConnect, Modbus, serial DNC) will too:

- `Backoff`: exponential delays, capped, with a little jitter (`backoff_delays`);
  they start over from `initial` after a connection that held (`stable_after`),
  or when the caller says so (`reset`).
- `OutageLog`: a link that is down for an hour must not write a line per attempt.
  The first failure of an outage is said at the caller's level (WARNING unless
  it asks otherwise), and again when the reason changes or, if asked, every
  `remind_every` seconds; the repeats in between go to DEBUG and are counted.
  When the link is back, that is said once, with how many attempts failed.

Jitter matters in a shop with many machines behind one gateway: when a switch
reboots, every driver loses its controller at the same instant, and without
jitter they would all retry in lockstep. The jitter only ever shortens a delay,
so the configured maximum really is the maximum. No I/O and no asyncio here:
callers sleep and log through the objects they hold.
"""

from __future__ import annotations

import logging
import random
import time
from collections.abc import Callable, Iterator
from typing import Protocol


def backoff_delays(
    initial: float,
    factor: float,
    maximum: float,
    *,
    jitter: float = 0.1,
    rand: Callable[[], float] = random.random,
) -> Iterator[float]:
    """Endless delays: initial, initial*factor, … capped at maximum, each shortened by up to `jitter`."""
    base = min(initial, maximum)
    while True:
        yield base * (1.0 - jitter * rand())
        base = min(base * factor, maximum)


class BackoffShape(Protocol):
    """The three numbers of a config's backoff section (gateway.settings.base.Backoff has them)."""

    @property
    def initial(self) -> float: ...

    @property
    def factor(self) -> float: ...

    @property
    def max(self) -> float: ...


class Backoff:
    """The delays of one reconnect loop; they start over after a connection that lasted `stable_after` s.

    A link that drops at once after every connection (a broker refusing our
    client id, a receiver that closes as soon as it reads) keeps backing off;
    one that held for a while is retried from `initial` when it drops.
    """

    def __init__(
        self,
        initial: float,
        factor: float,
        maximum: float,
        *,
        stable_after: float | None = None,
        jitter: float = 0.1,
        rand: Callable[[], float] = random.random,
        clock: Callable[[], float] = time.monotonic,
    ) -> None:
        self.initial = initial
        self.factor = factor
        self.maximum = maximum
        self.stable_after = stable_after
        self.jitter = jitter
        self.last_delay = 0.0  # the delay `next()` gave last
        self._rand = rand
        self._clock = clock
        self._delays = self._fresh()
        self._since: float | None = None

    @classmethod
    def of(cls, shape: BackoffShape, *, stable_after: float | None = None) -> Backoff:
        """From a config section with `initial`, `factor` and `max`."""
        return cls(shape.initial, shape.factor, shape.max, stable_after=stable_after)

    def _fresh(self) -> Iterator[float]:
        return backoff_delays(self.initial, self.factor, self.maximum, jitter=self.jitter, rand=self._rand)

    def next(self) -> float:
        """How long to wait before the next attempt."""
        self.last_delay = next(self._delays)
        return self.last_delay

    def reset(self) -> None:
        """Start over from `initial` (the link works again)."""
        self._delays = self._fresh()

    def connected(self) -> None:
        """A connection is up: `ended()` measures from now."""
        self._since = self._clock()

    def ended(self) -> bool:
        """The connection is gone; True (and the delays start over) if it lasted `stable_after` s."""
        since, self._since = self._since, None
        held = (
            since is not None and self.stable_after is not None and self._clock() - since >= self.stable_after
        )
        if held:
            self.reset()
        return held


class OutageLog:
    """Says a failure once at its level, quietly (DEBUG, counted) while it repeats, and the recovery once.

    `failed()` is called for every failed attempt, with a short `reason` that
    tells failures apart (`connection refused`, `timed out`): the first of an
    outage, a new reason, and (with `remind_every`) one line every so many
    seconds are written at the level asked for; the rest at DEBUG. `recovered()`
    writes its line at INFO, adding how many attempts failed before it, and ends
    the outage.
    """

    def __init__(
        self,
        logger: logging.Logger,
        *,
        remind_every: float | None = None,
        clock: Callable[[], float] = time.monotonic,
    ) -> None:
        self.logger = logger
        self.remind_every = remind_every
        self.failures = 0  # failed attempts in this outage
        self.quiet = 0  # of which were written at DEBUG only
        self.reason = ""  # the latest failure's reason ("" while the link is up)
        self._clock = clock
        self._said_at = 0.0

    @property
    def down(self) -> bool:
        return self.failures > 0

    def failed(
        self,
        reason: str,
        message: str,
        *args: object,
        level: int = logging.WARNING,
        exc_info: BaseException | None = None,
    ) -> bool:
        """Log one failed attempt (`message % args`); True if it was written at `level`, not DEBUG.

        `exc_info` (an unexpected error's traceback) goes only with a line written at `level`.
        """
        now = self._clock()
        loud = (
            self.failures == 0
            or reason != self.reason
            or (self.remind_every is not None and now - self._said_at >= self.remind_every)
        )
        self.failures += 1
        self.reason = reason
        if loud:
            self._said_at = now
            self.logger.log(level, message, *args, exc_info=exc_info)
        else:
            self.quiet += 1
            self.logger.debug(message, *args)
        return loud

    def recovered(self, message: str, *args: object, level: int = logging.INFO) -> None:
        """The link works: log `message % args` (with the failed attempts before it) and end the outage."""
        if self.failures:
            attempts = "attempt" if self.failures == 1 else "attempts"
            self.logger.log(level, f"{message} (after %d failed {attempts})", *args, self.failures)
        else:
            self.logger.log(level, message, *args)
        self.clear()

    def clear(self) -> None:
        """End the outage without a line (the caller said what happened itself)."""
        self.failures = 0
        self.quiet = 0
        self.reason = ""
