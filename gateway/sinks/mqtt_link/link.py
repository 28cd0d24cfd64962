"""What the MQTT and the Sparkplug sink do alike with their broker: keep the connection, say how it is.

`BrokerLink` is the part of both sinks that is about the link, not about what goes over it: the
settings of the one connection, built from the section's broker keys (`broker_settings`); the state
the diagnostics show (connecting, connected, disconnected with the reason) and its counters; the
reconnect loop with its backoff (gateway/reconnect.py) and the outage said once a while, not per
attempt; the store-and-forward backlog opened, committed and closed. Each sink keeps its own words
(`Wording`) and logger, so its log lines are its own.
"""

from __future__ import annotations

import asyncio
import logging
from collections.abc import Awaitable, Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any, TypeVar

from gateway.errors import BrokerError, BrokerRefused
from gateway.reconnect import Backoff, BackoffShape, OutageLog
from gateway.sinks.base import SinkHealth
from gateway.sinks.mqtt_link.broker import BrokerConnection
from gateway.sinks.mqtt_link.buffer import Backlog, Journal
from gateway.sinks.mqtt_link.client import BrokerSettings, Will, tls_context

STABLE_AFTER = 10.0  # s a connection must last before the reconnect backoff starts again from `initial`
REMIND_EVERY = 60.0  # s between "still away" log lines during an outage

STATE_CONNECTING, STATE_CONNECTED, STATE_DISCONNECTED = "connecting", "connected", "disconnected"

_Opened = TypeVar("_Opened")


@dataclass(frozen=True, slots=True)
class Wording:
    """How a sink's log lines name it and what it keeps for the broker."""

    label: str  # "MQTT": the start of each line
    check: str  # what to check when the broker refuses the login
    waiting: str  # "messages waiting": the backlog while connecting
    kept: str  # "messages": the backlog kept in the journal for the next start
    lost: str  # "messages": the backlog lost at a stop without a journal


def broker_settings(
    broker: BrokerConnection,
    base_dir: Path | None,
    *,
    client_id: str,
    max_packet_size: int,
    will: Will | None = None,
    no_delay: bool = False,
) -> BrokerSettings:
    """The connection's settings from a section's broker keys (TLS files relative to `base_dir`)."""
    tls = broker.tls
    return BrokerSettings(
        host=broker.host,
        port=broker.port,
        client_id=client_id,
        username=broker.username,
        password=broker.password.get_secret_value() if broker.password is not None else None,
        protocol=broker.protocol,
        keepalive=broker.keepalive,
        connect_timeout=broker.connect_timeout,
        tls=tls_context(tls, base_dir or Path.cwd()) if tls is not None else None,
        tls_verify=tls.verify if tls is not None else True,
        max_packet_size=max_packet_size,
        will=will,
        no_delay=no_delay,
    )


class BrokerLink:
    """A sink's link to its broker: settings, state, counters, the reconnect loop and the backlog."""

    def __init__(
        self, settings: BrokerSettings, reconnect: BackoffShape, wording: Wording, log: logging.Logger
    ) -> None:
        self.settings = settings
        self.wording = wording
        self.state = STATE_CONNECTING
        self.last_error = ""
        self.connects = 0  # successful connections
        self.attempts = 0  # failed ones
        self.last_delay = 0.0  # the backoff before the latest retry
        self.backlog: Backlog | None = None
        self._reconnect = reconnect
        self._log = log
        self._outage = OutageLog(log, remind_every=REMIND_EVERY)  # the broker's absence, said once a while

    @property
    def endpoint(self) -> str:
        return self.settings.address

    def _set_state(self, state: str, reason: str) -> None:
        self.state, self.last_error = state, reason

    # --- the connection -------------------------------------------------------------------------

    async def _keep_connected(
        self, connect: Callable[[], Awaitable[_Opened]], session: Callable[[_Opened], Awaitable[bool]]
    ) -> None:
        """Connect, run the session until it ends, again; until cancelled. `session` returns True when it
        ended on purpose (connect again at once), False when the connection was lost."""
        backoff = Backoff.of(self._reconnect, stable_after=STABLE_AFTER)
        while True:
            self._set_state(STATE_CONNECTING, self.last_error)
            try:
                opened = await connect()
            except BrokerError as exc:
                delay = backoff.next()
                self.attempts += 1
                self.last_delay = delay
                self._connect_failed(exc, delay)
                await asyncio.sleep(delay)
                continue
            backoff.connected()
            if await session(opened):
                continue
            if not backoff.ended():  # a broker that drops us at once (ACL, a twin with our client id)
                await asyncio.sleep(backoff.next())  # is not hammered

    def _connect_failed(self, exc: BrokerError, delay: float) -> None:
        reason = exc.reason
        self._set_state(STATE_DISCONNECTED, reason)
        waiting = len(self.backlog) if self.backlog is not None else 0
        w = self.wording
        if isinstance(exc, BrokerRefused):
            self._outage.failed(
                reason,
                f"{w.label}: %s; {w.check}. Retrying in %.1f s (%d {w.waiting})",
                reason, delay, waiting,
                level=logging.ERROR,
            )  # fmt: skip
        else:
            self._outage.failed(
                reason, f"{w.label}: %s; retrying in %.1f s (%d {w.waiting})", reason, delay, waiting
            )

    # --- store-and-forward ----------------------------------------------------------------------

    def _open_backlog(self, limit: int, journal: Path | None) -> Backlog:
        """The backlog, mirrored into the SQLite file `journal` when there is one (buffer.persist)."""
        self.backlog = Backlog(limit, Journal(journal) if journal is not None else None)
        return self.backlog

    def _close_backlog(self) -> None:
        """On the way out: what is still waiting stays in the journal, or is lost and said so."""
        backlog = self.backlog
        if backlog is None:
            return
        w = self.wording
        if backlog.journal is not None:
            waiting = backlog.counted
            backlog.journal.close()
            if waiting:
                self._log.info(
                    f"{w.label}: %d {w.kept} kept in %s for the next start", waiting, backlog.journal.path
                )
        elif backlog.counted:
            self._log.warning(
                f"{w.label}: %d {w.lost} were not delivered (buffer.persist is off)", backlog.counted
            )

    def _commit(self) -> None:
        backlog = self.backlog
        if backlog is not None and backlog.journal is not None:
            backlog.journal.commit()

    def _health(self, *, ready: bool, in_flight: int, online: bool, **figures: Any) -> SinkHealth:
        """The link's part of the sink's health; `figures` the sink's own (SinkHealth's other fields)."""
        backlog = self.backlog
        return SinkHealth(
            ready=ready,
            state=self.state,
            backlog=len(backlog) if backlog is not None else None,
            dropped=backlog.dropped_total if backlog is not None else None,
            in_flight=in_flight,
            connects=self.connects,
            online=online,
            last_error=self.last_error,
            **figures,
        )
