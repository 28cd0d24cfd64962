"""The running gateway: one variable tree, its sources and sinks, one TaskGroup.

Start-up order matters to users: sinks start first, so that SCADA clients can
browse the tree (with Bad values) even while controllers are still unreachable;
then the sources connect. Shutdown is the reverse, and quick.
"""

from __future__ import annotations

import asyncio
import logging
import signal
from collections.abc import Awaitable, Callable
from contextlib import AsyncExitStack
from typing import Any, Self

from gateway.config.loader import Config
from gateway.model.tree import VariableTree
from gateway.sinks.base import Sink
from gateway.sources.base import Source, create_source

log = logging.getLogger("gateway")


def build_sinks(config: Config, tree: VariableTree) -> list[Sink]:
    from gateway.sinks.opcua.server import OpcUaSink

    sinks: list[Sink] = [OpcUaSink(tree, config.gateway.opcua, config.state_dir)]
    if config.gateway.mqtt is not None:  # no `mqtt:` in the gateway file: no broker to reach
        from gateway.sinks.mqtt.sink import MqttSink

        sinks.append(MqttSink(tree, config.gateway.mqtt, config.state_dir, base_dir=config.base_dir))
    if any(m.copydata is not None for m in config.machines):  # frames for nesting software
        from gateway.sinks.copydata.sink import CopydataSink

        sinks.append(CopydataSink(tree))
    return sinks


def build_jobs(config: Config, tree: VariableTree) -> Any:
    """The FTP job queue, when some machine has a `jobs:` section (None otherwise)."""
    if not any(m.jobs is not None for m in config.machines):
        return None
    from gateway.jobs.service import JobService

    return JobService(config, tree)


class Gateway:
    """Owns every component; `async with Gateway(config) as gw: await gw.run()`."""

    def __init__(self, config: Config) -> None:
        self.config = config
        self.tree = VariableTree(config.machines)
        self.sinks: list[Sink] = build_sinks(config, self.tree)
        self.sources: list[Source] = [create_source(m) for m in self.tree.machines.values()]
        self.jobs = build_jobs(config, self.tree)  # before the sinks start: it adds Jobs/ variables and methods
        self.ready = asyncio.Event()
        self._stack = AsyncExitStack()

    def sink(self, name: str) -> Any:
        for sink in self.sinks:
            if sink.name == name:
                return sink
        raise KeyError(name)

    async def __aenter__(self) -> Self:
        self.config.state_dir.mkdir(parents=True, exist_ok=True)
        try:
            for sink in self.sinks:
                await self._stack.enter_async_context(sink)
            for source in self.sources:
                await self._stack.enter_async_context(source)
            if self.jobs is not None:
                await self._stack.enter_async_context(self.jobs)
        except BaseException:
            await self._stack.aclose()
            raise
        return self

    async def __aexit__(self, *exc_info: object) -> None:
        await self._stack.aclose()

    async def run(self, *extra: tuple[str, Callable[[], Awaitable[None]]]) -> None:
        """Run every component until cancelled. `extra` adds named tasks (the demo's driver)."""
        async with asyncio.TaskGroup() as tg:
            for sink in self.sinks:
                tg.create_task(sink.run(), name=f"sink:{sink.name}")
            for source in self.sources:
                tg.create_task(source.run(), name=f"source:{source.machine.name}")
            if self.jobs is not None:
                tg.create_task(self.jobs.run(), name="jobs")
            for name, factory in extra:
                tg.create_task(factory(), name=name)
            self.ready.set()


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
        try:
            loop.add_signal_handler(sig, stop, sig)
        except (NotImplementedError, RuntimeError):  # pragma: no cover - Windows
            pass
    try:
        await task
    except asyncio.CancelledError:
        if not task.cancelled():
            raise
    finally:
        for sig in signals:
            try:
                loop.remove_signal_handler(sig)
            except (NotImplementedError, RuntimeError):  # pragma: no cover - Windows
                pass
