"""The MTConnect agent sink: the mirror served as an MTConnect 2.4 agent (HTTP, port 5000 by default).

One sink per gateway (gateway.sinks.base.Sink), built when the gateway file has an
`mtconnect:` section. Its parts: the profile (profile.py: machines as Devices), the
agent (agent.py: the buffer and the documents), the HTTP server (http.py, aiohttp),
and, with `persist: true`, the buffer on disk (store.py). Tasks: the feed (every change,
in order, from its hub subscription: `every_change`, bounded by the buffer's size),
the events (alarms, programs) and the writer of the buffer file.
"""

from __future__ import annotations

import asyncio
import functools
import hashlib
import logging
from collections.abc import Callable, Mapping
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path
from typing import Any, Self, TypeVar

from gateway.codecs.mtconnect.buffer import Entry
from gateway.codecs.mtconnect.errors import ModelError
from gateway.errors import SinkError
from gateway.model.events import EventSubscription
from gateway.model.hub import Subscription
from gateway.model.tree import VariableNode, VariableTree
from gateway.sinks.base import SinkHealth
from gateway.sinks.http_listener import Limits
from gateway.sinks.mtconnect.agent import Agent
from gateway.sinks.mtconnect.config import AgentConfig, AgentMachineEntry
from gateway.sinks.mtconnect.http import AgentServer
from gateway.sinks.mtconnect.profile import build_profile
from gateway.sinks.mtconnect.store import ObservationStore, Row, store_path

log = logging.getLogger("gateway.sinks.mtconnect")

T = TypeVar("T")
PERSIST_EVERY = 0.25  # s between writes of the buffer file


class MTConnectSink:
    name = "mtconnect"

    def __init__(
        self,
        tree: VariableTree,
        config: AgentConfig,
        mappings: Mapping[str, AgentMachineEntry],
        state_dir: Path,
    ) -> None:
        self.tree = tree
        self.config = config
        self.state_dir = state_dir
        try:
            self.profile = build_profile(tree, mappings, config)
            self.agent = Agent(self.profile, config)
        except ModelError as exc:
            raise SinkError(f"the MTConnect device model is not valid: {exc}") from None
        self.server = AgentServer(
            self.agent,
            config.host,
            config.port,
            max_streams=config.max_streams,
            limits=Limits.of(config.connections),
        )
        self.store: ObservationStore | None = None
        self._pool: ThreadPoolExecutor | None = None
        self._persisted = 0
        self._changes: Subscription[VariableNode] | None = None
        self._events: EventSubscription | None = None

    @property
    def url(self) -> str:
        return self.server.url

    async def db(self, fn: Callable[..., T], *args: Any) -> T:
        assert self._pool is not None
        return await asyncio.get_running_loop().run_in_executor(self._pool, functools.partial(fn, *args))

    async def __aenter__(self) -> Self:
        try:
            if self.config.persist:
                await self._open_store()
            tree = self.tree
            self._changes = tree.hub.subscribe("mtconnect", every_change=True, limit=self.config.buffer_size)
            self._events = tree.events.subscribe("mtconnect")
            nodes = [*self.profile.bindings, *self.profile.connected]
            self.agent.start(nodes)
            await self.server.__aenter__()
        except BaseException:
            await self._close()
            raise
        log.info(
            "MTConnect agent on %s (%d devices, %d data items, buffer %d, instanceId %d%s)",
            self.server.url,
            len(self.profile.devices),
            len(self.agent.catalog.items),
            self.agent.buffer.size,
            self.agent.buffer.instance_id,
            ", kept on disk" if self.store is not None else "",
        )
        return self

    async def __aexit__(self, *exc_info: object) -> None:
        await self.server.__aexit__(*exc_info)
        await self._close()

    async def _close(self) -> None:
        for sub in (self._changes, self._events):
            if sub is not None:
                sub.close()
        self._changes = self._events = None
        store, self.store = self.store, None
        if store is not None:
            try:
                rows, keep_from = self._rows()
                await self.db(store.append, rows, keep_from)
                await self.db(store.finish, self.agent.buffer.next_sequence)
            except SinkError as exc:
                log.error("MTConnect: the buffer file was not closed cleanly: %s", exc)
            finally:
                await self.db(store.close)
        pool, self._pool = self._pool, None
        if pool is not None:
            await asyncio.to_thread(pool.shutdown, True)

    # --- the buffer on disk ----------------------------------------------------------------------

    async def _open_store(self) -> None:
        self._pool = ThreadPoolExecutor(1, thread_name_prefix="mtconnect-db")
        store = ObservationStore(store_path(self.state_dir))
        await self.db(store.open)
        self.store = store
        buffer = self.agent.buffer
        fingerprint = hashlib.sha256(repr(self.agent.catalog.devices).encode()).hexdigest()
        kept, why = await self.db(store.kept, fingerprint, buffer.size)
        fresh = kept is None
        if kept is not None:
            try:
                self._restore(kept.instance_id, kept.next_sequence, kept.rows)
            except (ValueError, KeyError) as exc:
                fresh, why = True, f"the kept buffer cannot be read back ({exc})"
        if fresh:
            if why != "no earlier run":
                log.warning("MTConnect: starting a new buffer (instanceId changes): %s", why)
        else:
            log.info(
                "MTConnect: buffer kept from the last run: instanceId %d, sequences %d to %d",
                buffer.instance_id,
                buffer.first_sequence,
                buffer.last_sequence,
            )
        self._persisted = buffer.next_sequence
        await self.db(functools.partial(store.begin, fresh=fresh), fingerprint, buffer.instance_id)

    def _restore(self, instance_id: int, next_sequence: int, rows: list[Row]) -> None:
        items = self.agent.catalog.items
        entries = [
            Entry(
                r[0], items[r[1]], r[2], r[3], r[4], r[5], r[6], r[7], r[8], r[9], r[10], r[11], r[12], r[13]
            )
            for r in rows
        ]
        agent = self.agent
        fresh_buffer = agent.buffer
        fresh_buffer.instance_id = instance_id
        if entries and entries[-1].sequence + 1 == next_sequence:
            fresh_buffer.restore(entries)
        else:
            fresh_buffer.resume_at(next_sequence)

    def _rows(self) -> tuple[list[Row], int]:
        buffer = self.agent.buffer
        start, stop = self._persisted, buffer.next_sequence
        rows: list[Row] = [
            (e.sequence, e.info.item.id, e.timestamp, e.value, e.level, e.native_code, e.native_severity,
             e.qualifier, e.condition_id, e.sample_count, e.sample_rate, e.reset_triggered, e.duration,
             e.asset_type)
            for e in buffer.entries_between(start, stop)
        ]  # fmt: skip
        self._persisted = stop
        return rows, buffer.first_sequence

    async def _persist(self) -> None:
        while True:
            await asyncio.sleep(PERSIST_EVERY)
            store = self.store
            if store is None:
                return
            rows, keep_from = self._rows()
            if rows:
                try:
                    await self.db(store.append, rows, keep_from)
                except SinkError as exc:
                    log.error("MTConnect: observations not written to the buffer file: %s", exc)

    # --- running ---------------------------------------------------------------------------------

    def health(self) -> SinkHealth:
        """Ready once entered: the agent's port is bound there, or the start stopped."""
        return SinkHealth(ready=True)

    async def run(self) -> None:
        async with asyncio.TaskGroup() as tg:
            tg.create_task(self._feed(), name="mtconnect:feed")
            tg.create_task(self._follow_events(), name="mtconnect:events")
            if self.store is not None:
                tg.create_task(self._persist(), name="mtconnect:persist")

    async def _feed(self) -> None:
        sub = self._changes
        assert sub is not None
        agent = self.agent
        while True:
            agent.feed(await sub.next_batch())

    async def _follow_events(self) -> None:
        sub = self._events
        assert sub is not None
        while True:
            for event in await sub.next_batch():
                self.agent.on_event(event)
