"""The running gateway: one variable tree, its sources and sinks, one TaskGroup.

Start-up: the sources begin to connect first, and connect while the sinks start
(an OPC UA server of 10,000 variables takes about a second to build: the
controllers' sessions and subscriptions are made meanwhile, not after it). Each
sink subscribes to the hub before it reads the tree's current samples, so a value
that arrives while it starts is in one or the other; a sink's task starts as soon
as it is up. SCADA clients can still browse the tree (with Bad values) while
controllers are unreachable. Shutdown stops every task, then leaves the
components in the reverse order, quickly.
"""

from __future__ import annotations

import asyncio
import contextlib
import gc
import logging
import signal
from collections.abc import Awaitable, Callable, Coroutine
from contextlib import AsyncExitStack
from typing import TYPE_CHECKING, Any, Self, TypeVar, overload

from gateway.audit.tables import where_of
from gateway.audit.trail import AuditTrail
from gateway.auth.ratelimit import LoginLimiter
from gateway.commands.runner import install_commands
from gateway.config.loader import Config
from gateway.model.tree import VariableTree
from gateway.shims.heap import HeapHold
from gateway.sinks.base import Sink, SinkContext
from gateway.sinks.registry import SINKS
from gateway.sources.base import Source
from gateway.sources.registry import create_source

if TYPE_CHECKING:  # imported where they are built, only when the configuration asks for them
    from gateway.alarms.service import AlarmService
    from gateway.jobs.service import JobService
    from gateway.shards.holder import LeaseHolder

log = logging.getLogger("gateway")

# The heap is settled (gateway/shims/heap.py: one full collection, then frozen) once every machine has
# been tried and their first values have had this long to flow out, or this long after start-up at the
# latest: the pass (about 0.2 s with 10,000 variables) then falls after the start-up burst, not in it.
SETTLE_AFTER_MACHINES = 1.0
SETTLE_AT_LATEST = 15.0

S = TypeVar("S", bound=Sink)


def configure_access(config: Config, tree: VariableTree) -> None:
    """Roles, whether they are enforced, the roles of callers without a login (gateway/model/access.py)."""
    gw = config.gateway
    access = gw.access

    def door(role: str | None) -> str | None:
        return access.door_role(role, gw.users, gw.roles)

    tree.access.configure(
        gw.roles,
        enabled=access.checks_roles(),  # with or without users: anonymous OPC UA clients get their role
        default_write_role=access.default_write_role,
        # COPYDATA has no login and no door role of its own: only the one the gateway file names (the loader
        # refuses a target that accepts writes without it), never the highest for want of users.
        origin_roles={"jobs": door(access.jobs_role), "copydata": access.copydata_role},
        mqtt_roles={
            m.machine: door(m.mqtt.writer_role if m.mqtt and m.mqtt.writer_role else access.mqtt_writer_role)
            for m in config.machines
        },
    )
    if not tree.access.enabled:
        log.warning(
            "access.enabled is false: no role is checked; every client may change what the mappings allow"
        )
    elif access.is_enabled(gw.users):
        log.info(
            "access control on: %d user(s), roles %s, anonymous OPC UA logins: %s",
            len(gw.users),
            " < ".join(gw.roles),
            access.anonymous,
        )
    else:
        log.info(
            "no users: OPC UA clients are anonymous, with role %s (access.anonymous); writes and commands "
            "that mappings open to MQTT act as %s; COPYDATA writes as %s (access.copydata_role)",
            access.anonymous,
            gw.roles[-1],
            access.copydata_role or "nobody: refused",
        )


def build_sinks(gateway: Gateway) -> list[Sink]:
    """The sinks the configuration asks for, in the registry's order (gateway/sinks/registry.py): each
    spec builds its sink from the context, or answers None when its section is absent."""
    config = gateway.config
    context = SinkContext(
        tree=gateway.tree,
        config=config,
        mappings=config.mappings,
        state_dir=config.state_dir,
        base_dir=config.base_dir,
        logins=gateway.logins,
        host=gateway,
        audit=gateway.audit,
        jobs=gateway.jobs.port if gateway.jobs is not None else None,
        alarms=gateway.alarms,
    )
    built = (spec.create(context) for spec in SINKS)
    return [sink for sink in built if sink is not None]


def build_jobs(
    config: Config,
    tree: VariableTree,
    logins: LoginLimiter | None = None,
    lease: LeaseHolder | None = None,
) -> JobService | None:
    """The FTP job queue, when some machine has a `jobs:` section (None otherwise)."""
    if not any(m.jobs is not None for m in config.machines):
        return None
    from gateway.jobs.service import JobService

    return JobService(config, tree, logins=logins, lease=lease)


def build_leases(config: Config) -> LeaseHolder | None:
    """`shard: lease`: this process's leases on the fleet's machines, in the queue's database."""
    gw = config.gateway
    if not gw.leased or gw.queue is None:
        return None
    from gateway.shards.holder import LeaseHolder, holder_name

    machines = [m.machine for m in config.machines]
    return LeaseHolder(gw.queue, holder_name(), machines, lease_time=gw.lease_time)


def build_sources(config: Config, tree: VariableTree, leases: LeaseHolder | None) -> list[Source]:
    """Each machine's source; with leases, each run only while this process holds its machine."""
    mappings = config.mappings
    sources = [create_source(m, mappings[n]) for n, m in tree.machines.items()]
    if leases is None:
        return sources
    from gateway.sources.leased import LeasedSource

    return [LeasedSource(source, leases) for source in sources]


def build_alarms(config: Config, tree: VariableTree) -> AlarmService | None:
    """The alarm managers, when some machine has an `alarms:` section (None otherwise)."""
    if not any(m.alarms is not None for m in config.machines):
        return None
    from gateway.alarms.service import AlarmService

    return AlarmService(tree, config.mappings, config.state_dir, config.gateway.alarm_history)


class Gateway:
    """Owns every component; `async with Gateway(config) as gw: await gw.run()`."""

    def __init__(self, config: Config, *, collector: bool | None = None) -> None:
        """`collector`: whether Python's cyclic collector runs once start-up is over (None: as on entry;
        `cnc-gateway run` pauses it while it loads the configuration, and passes True)."""
        self.config = config
        self._collector = collector
        # The tree gets the model's definitions; components that read the rest of a mapping get the mappings.
        self.tree = VariableTree(config.definitions())
        configure_access(config, self.tree)
        retention = config.gateway.access.audit_retention
        self.audit = AuditTrail(where_of(config.gateway.audit, config.state_dir), retention_days=retention)
        self.tree.audit_sinks.append(self.audit.record)
        mappings = config.mappings
        install_commands(self.tree, mappings)  # the commands as Commands/ methods, before the sinks see them
        self.alarms = build_alarms(config, self.tree)
        # One failed-login lockout for every door that checks passwords (OPC UA, web, FTP inbox): guesses
        # on one door count against the others from the same address.
        self.logins = config.gateway.login_limiter()
        self.leases = build_leases(config)  # shard: lease (None: this process serves every machine it loads)
        # Before the sinks are built: the job service adds Jobs/ variables and methods (Programs, and a
        # serial machine's Commands/Drip*, which the MQTT sink's command requests list when built).
        self.jobs = build_jobs(config, self.tree, self.logins, self.leases)
        self.sources: list[Source] = build_sources(config, self.tree, self.leases)
        # After the job service (the console submits through it), with the drivers built: each sink's
        # __init__ adds the variables it reports on, which the sinks built after it see.
        self.sinks: list[Sink] = build_sinks(self)
        self.ready = asyncio.Event()
        self._stack = AsyncExitStack()
        self._heap: HeapHold | None = None  # from __aenter__ until start-up is over
        # The one TaskGroup of every component's task, from __aenter__ (the sources', then each sink's as it
        # is up) to __aexit__; run() adds the job service's, the alarms' and its own extras.
        self._group: asyncio.TaskGroup | None = None
        self._tasks: list[asyncio.Task[None]] = []

    @overload
    def sink(self, name: str) -> Sink: ...

    @overload
    def sink(self, name: str, kind: type[S]) -> S: ...

    def sink(self, name: str, kind: type[Sink] | None = None) -> Sink:
        """The sink called `name` (KeyError if none); with `kind`, checked to be that class."""
        for sink in self.sinks:
            if sink.name == name:
                if kind is not None and not isinstance(sink, kind):
                    raise TypeError(f"sink {name!r} is a {type(sink).__name__}, not a {kind.__name__}")
                return sink
        raise KeyError(name)

    def diagnostics(self) -> dict[str, Any]:
        """gateway/diagnostics.py's snapshot (the web console's GatewayPort)."""
        from gateway.diagnostics import snapshot

        return snapshot(self)

    def not_ready(self) -> list[str]:
        """What keeps the gateway from being ready: start-up, a sink not up, a machine not yet tried."""
        waiting = [] if self.ready.is_set() else ["start-up"]
        waiting.extend(f"sink {sink.name}" for sink in self.sinks if not sink.health().ready)
        for name, machine in self.tree.machines.items():
            status = machine.status
            if not (status.is_connected or status.last_error):
                waiting.append(f"machine {name}")
        return waiting

    async def __aenter__(self) -> Self:
        self.config.state_dir.mkdir(parents=True, exist_ok=True)
        self._heap = HeapHold(self._collector)  # no collector passes until start-up is over (_settle_heap)
        try:
            await self._stack.enter_async_context(self.audit)  # first in, last out: it sees every write
            if self.alarms is not None:  # before the sinks: OPC UA offers the alarms open from the start
                await self._stack.enter_async_context(self.alarms)
            if self.leases is not None:  # a first share taken; released last but one, after the sources
                await self._stack.enter_async_context(self.leases)
            for source in self.sources:  # cheap: the machine's writer, its invalid addresses
                await self._stack.enter_async_context(source)
            self._group = asyncio.TaskGroup()
            await self._group.__aenter__()
            # The controllers' sessions are opened while the sinks start: a sink reads the tree's samples
            # after it has subscribed to the hub, so a value a source brings meanwhile reaches it.
            if self.leases is not None:
                self._start(self.leases.run(), "leases")
            for source in self.sources:
                self._start(source.run(), f"source:{source.machine.name}")
            for sink in self.sinks:
                await self._stack.enter_async_context(sink)
                self._start(sink.run(), f"sink:{sink.name}")
            if self.jobs is not None:
                await self._stack.enter_async_context(self.jobs)
            self._start(self._settle_heap(), "heap:settle")
        except BaseException:
            try:
                await self._stop_tasks()  # a task's own failure, if any, is raised from here (as a group)
            finally:
                await self._stack.aclose()
                self._heap.release()
            raise
        return self

    async def _settle_heap(self) -> None:
        """Settle the heap once the start-up burst is over: every machine tried (connected, or failed with
        its error) and its first values out, or SETTLE_AT_LATEST after start-up, whichever comes first."""
        loop = asyncio.get_running_loop()
        latest = loop.time() + SETTLE_AT_LATEST
        machines = list(self.tree.machines.values())

        def all_tried() -> bool:
            return all(m.status.is_connected or m.status.last_error for m in machines)

        # Polled: a machine's status has no event of its own, and a tenth of a second is fine enough here.
        while loop.time() < latest and not all_tried():  # noqa: ASYNC110
            await asyncio.sleep(0.1)
        await asyncio.sleep(max(0.0, min(SETTLE_AFTER_MACHINES, latest - loop.time())))
        if self._heap is not None:
            self._heap.settle()

    def _start(self, coro: Coroutine[object, object, None], name: str) -> None:
        assert self._group is not None, "enter the gateway first"
        self._tasks.append(self._group.create_task(coro, name=name))

    async def _stop_tasks(self) -> None:
        """Cancel every component's task and wait for them (a task's failure is raised, as a group)."""
        group, self._group = self._group, None
        if group is None:
            return
        for task in self._tasks:
            task.cancel()
        self._tasks = []
        await group.__aexit__(None, None, None)

    async def __aexit__(self, *exc_info: object) -> None:
        try:
            try:
                await self._stop_tasks()  # first: no sink or source task runs while the components close
            finally:
                await self._stack.aclose()
        finally:
            if self._heap is not None:
                self._heap.release()  # stopped before it settled: the collector as it was
            gc.unfreeze()  # what this gateway built becomes collectable again (tests run many in one process)

    async def run(self, *extra: tuple[str, Callable[[], Coroutine[object, object, None]]]) -> None:
        """Run every component until cancelled. `extra` adds named tasks (the demo's driver).

        The sources' and sinks' tasks are already running (since `__aenter__`); this adds the job
        service's, the alarms' and `extra`, in the same TaskGroup. Cancelling it stops them all."""
        if self._group is None:
            raise RuntimeError("enter the gateway before running it")
        if self.jobs is not None:
            self._start(self.jobs.run(), "jobs")
        if self.alarms is not None:
            self._start(self.alarms.run(), "alarms")
        for name, factory in extra:
            self._start(factory(), name)
        self.ready.set()
        try:
            if self._tasks:
                await asyncio.wait(self._tasks)  # every task ends only when cancelled, or when one fails
        except asyncio.CancelledError:
            await self._stop_tasks()
            raise


async def run_until_signalled(main: Awaitable[None]) -> None:
    """Run `main` until it ends or SIGINT/SIGTERM arrives; a signal cancels it cleanly."""
    loop = asyncio.get_running_loop()
    task = asyncio.ensure_future(main)
    task.set_name("main")
    signals = (signal.SIGINT, signal.SIGTERM)

    def stop(sig: signal.Signals) -> None:
        log.info("%s received, shutting down", sig.name)
        task.cancel()

    for sig in signals:
        with contextlib.suppress(NotImplementedError, RuntimeError):  # pragma: no cover - Windows
            loop.add_signal_handler(sig, stop, sig)
    try:
        await task
    except asyncio.CancelledError:
        if not task.cancelled():
            raise
    finally:
        for sig in signals:
            with contextlib.suppress(NotImplementedError, RuntimeError):  # pragma: no cover - Windows
                loop.remove_signal_handler(sig)
