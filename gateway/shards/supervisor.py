"""FleetSupervisor: N shard processes of one gateway file on one host, each restarted with backoff.

`cnc-gateway fleet FLEET.yaml` (issue 29). Each shard is `cnc-gateway run GATEWAY` in a
process of its own, told which shard it is by its environment (`CNC_SHARD=K/N`, its own
state directory and base ports plus K - 1: see gateway/config/fleet.py), so that one core
runs one shard and the death of one blinds only its machines. A shard that ends is started
again after a backoff that starts over once it has run for a while; a clean stop (SIGTERM
to the supervisor) sends SIGTERM to every shard, waits for them, and kills what is left
after `STOP_GRACE`. One line per shard says each start and end; `status()` is the table.

An async context manager like every long-running part of the gateway: `run()` keeps the
shards until cancelled, one named task per shard under one TaskGroup.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import os
import signal
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Self

from gateway.reconnect import Backoff, BackoffShape
from gateway.shards.parent import SUPERVISOR_ENV

log = logging.getLogger("gateway.fleet")

STOP_GRACE = 10.0  # s a shard has to stop after SIGTERM before it is killed
STABLE_AFTER = 30.0  # s a shard must run before its restart backoff starts over


@dataclass(frozen=True)
class ShardSpec:
    """One shard process: its number (1-based) of `of`, its command, its environment's additions."""

    number: int
    of: int
    command: Sequence[str]
    environ: Mapping[str, str]

    @property
    def label(self) -> str:
        return f"shard {self.number}/{self.of}"


@dataclass
class ShardState:
    spec: ShardSpec
    pid: int | None = None
    started: float | None = None  # monotonic time of the running process's start
    starts: int = 0
    last_exit: int | None = None  # the previous process's return code (negative: the signal)
    next_start: float | None = None  # monotonic time of the next start, while waiting for it
    _proc: asyncio.subprocess.Process | None = field(default=None, repr=False)

    @property
    def restarts(self) -> int:
        return max(0, self.starts - 1)

    def line(self, now: float) -> str:
        """The shard's status in one line."""
        extras = " ".join(f"{k}={v}" for k, v in sorted(self.spec.environ.items()) if k != "CNC_SHARD")
        if self.pid is not None and self.started is not None:
            state = f"pid {self.pid:<7} up {now - self.started:7.1f} s"
        elif self.next_start is not None:
            state = f"restarting in {max(0.0, self.next_start - now):.1f} s"
        else:
            state = "stopped"
        ended = f"  last exit {self.last_exit}" if self.last_exit is not None else ""
        return f"{self.spec.label:<12} {state:<28} restarts {self.restarts}{ended}  {extras}"


class FleetSupervisor:
    def __init__(
        self,
        shards: Sequence[ShardSpec],
        *,
        backoff: BackoffShape,
        base_environ: Mapping[str, str],
        on_change: Callable[[ShardState], None] | None = None,
        clock: Callable[[], float] = time.monotonic,
    ) -> None:
        self.states = [ShardState(spec) for spec in shards]
        self.backoff = backoff
        self.base_environ = dict(base_environ)
        self.on_change = on_change
        self.clock = clock

    async def __aenter__(self) -> Self:
        return self

    async def __aexit__(self, *exc_info: object) -> None:
        await asyncio.gather(*(self._stop(state) for state in self.states))

    async def run(self) -> None:
        """Keep every shard running until cancelled."""
        async with asyncio.TaskGroup() as tg:
            for state in self.states:
                tg.create_task(self._keep(state), name=f"fleet:shard-{state.spec.number}")

    def status(self) -> list[str]:
        now = self.clock()
        return [state.line(now) for state in self.states]

    def _changed(self, state: ShardState) -> None:
        if self.on_change is not None:
            self.on_change(state)

    async def _keep(self, state: ShardState) -> None:
        backoff = Backoff.of(self.backoff, stable_after=STABLE_AFTER)
        spec = state.spec
        while True:
            try:
                environ = {**self.base_environ, **spec.environ, SUPERVISOR_ENV: str(os.getpid())}
                proc = await asyncio.create_subprocess_exec(
                    *spec.command, env=environ, stdin=asyncio.subprocess.DEVNULL
                )
            except OSError as exc:
                log.error("fleet: %s cannot start: %s", spec.label, exc.strerror or exc)
                await self._wait(state, backoff.next())
                continue
            state._proc, state.pid, state.started = proc, proc.pid, self.clock()
            state.starts += 1
            state.next_start = None
            backoff.connected()
            log.info("fleet: %s started (pid %d)", spec.label, proc.pid)
            self._changed(state)
            code = await proc.wait()
            ran = self.clock() - (state.started or self.clock())
            state._proc, state.pid, state.started, state.last_exit = None, None, None, code
            delay = backoff.next() if not backoff.ended() else self.backoff.initial
            how = f"killed by {_signal_name(-code)}" if code < 0 else f"exit code {code}"
            log.warning(
                "fleet: %s ended (%s) after %.1f s; starting it again in %.1f s", spec.label, how, ran, delay
            )
            await self._wait(state, delay)

    async def _wait(self, state: ShardState, delay: float) -> None:
        state.next_start = self.clock() + delay
        self._changed(state)
        await asyncio.sleep(delay)

    async def _stop(self, state: ShardState) -> None:
        proc = state._proc
        if proc is None or proc.returncode is not None:
            return
        with contextlib.suppress(ProcessLookupError):
            proc.send_signal(signal.SIGTERM)
        try:
            await asyncio.wait_for(proc.wait(), STOP_GRACE)
        except TimeoutError:
            log.warning("fleet: %s did not stop within %.0f s; killed", state.spec.label, STOP_GRACE)
            with contextlib.suppress(ProcessLookupError):
                proc.kill()
            await proc.wait()
        state._proc, state.pid, state.started = None, None, None


def _signal_name(number: int) -> str:
    try:
        return signal.Signals(number).name
    except ValueError:
        return f"signal {number}"
