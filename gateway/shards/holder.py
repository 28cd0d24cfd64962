"""LeaseHolder: a shard's leases kept alive in the background, and the fencing token a side effect presents.

An async context manager like every long-running part of the gateway: entering opens the
lease table (and takes a first share), `run()` steps the LeaseKeeper every `lease_time / 3`
until cancelled, leaving releases every lease (a clean stop: the others take over at once).
A holder that dies without leaving (SIGKILL, a lost host) simply stops renewing, and its
leases run out after `lease_time` by the database's clock.

`fence(machine)` is what a side effect asks before it acts: the token of a lease this process
holds, or None. None also when this process's own clock says the lease may have run out
(`lease_time - margin` since the renewal was sent): the database's check refuses a stale token
in a transaction, but an upload to a controller happens outside any transaction, so a
holder that was paused (SIGSTOP, a stalled VM) must not start one on an old renewal.

Database calls run in one thread of their own, never on the event loop nor in asyncio's
shared default pool.
"""

from __future__ import annotations

import asyncio
import logging
import os
import socket
import time
from collections.abc import Callable, Collection
from concurrent.futures import ThreadPoolExecutor
from typing import Self, TypeVar

from gateway.errors import LeaseError
from gateway.shards.fence import Fence
from gateway.shards.keeper import LeaseKeeper, Round
from gateway.shards.leases import LeaseTable

log = logging.getLogger("gateway.shards")

T = TypeVar("T")


def holder_name() -> str:
    """This process among a fleet's members: its shard under `cnc-gateway fleet`, its host and pid (unique:
    a shard started again is a new member, which takes its machines when the old one's leases run out)."""
    shard = os.environ.get("CNC_SHARD", "").strip()
    where = f"{socket.gethostname()}:{os.getpid()}"
    return f"shard {shard} ({where})" if shard else where


class LeaseHolder:
    def __init__(
        self,
        url: str,
        holder: str,
        machines: Collection[str],
        *,
        lease_time: float = 10.0,
        margin: float | None = None,
        clock: Callable[[], float] = time.monotonic,
    ) -> None:
        self.holder = holder
        self.lease_time = lease_time
        self.margin = lease_time / 5 if margin is None else margin
        self.clock = clock
        self.table = LeaseTable(url, lease_time=lease_time)
        self.keeper = LeaseKeeper(self.table, holder, machines)
        self._renewed: dict[str, float] = {}  # machine -> local time the renewal that holds it was sent
        self._fences: dict[str, Fence] = {}
        self._pool: ThreadPoolExecutor | None = None
        self.changed = asyncio.Event()  # set after a step that took, lost or released a machine
        self._watchers: dict[str, list[Callable[[bool], None]]] = {}
        self._told: dict[str, bool] = {}  # what each machine's watchers were last told
        self.reachable = True  # False while the lease table cannot be reached (the last step failed)

    async def _call(self, fn: Callable[[], T]) -> T:
        assert self._pool is not None, "the lease holder is not entered"
        return await asyncio.get_running_loop().run_in_executor(self._pool, fn)

    async def __aenter__(self) -> Self:
        self._pool = ThreadPoolExecutor(1, thread_name_prefix="cnc-leases")
        try:
            await self._call(self.table.open)
            await self.step()
            self._tell()
        except BaseException:
            self._pool.shutdown(wait=False)
            self._pool = None
            raise
        return self

    async def __aexit__(self, *exc_info: object) -> None:
        self._fences.clear()
        self._tell()  # the watchers stop serving before the leases are released
        try:
            await self._call(self.keeper.stop)
        except LeaseError as exc:
            log.warning("%s: could not release its leases (they run out on their own): %s", self.holder, exc)
        finally:
            await self._call(self.table.close)
            assert self._pool is not None
            self._pool.shutdown(wait=False)
            self._pool = None

    async def step(self) -> Round:
        sent = self.clock()
        done = await self._call(self.keeper.step)
        self._fences = {m: lease.fence for m, lease in self.keeper.leases.items()}
        for machine in self._fences:
            self._renewed[machine] = sent
        for machine in (*done.lost, *done.released):
            self._renewed.pop(machine, None)
        if done.taken or done.lost or done.released:
            log.info(
                "%s: holds %d machine(s); took %s, lost %s, released %s",
                self.holder,
                len(self._fences),
                done.taken or "none",
                done.lost or "none",
                done.released or "none",
            )
            self.changed.set()
        return done

    async def run(self) -> None:
        """Renew, rebalance and take over, every third of the lease time, until cancelled; the watchers
        hear of every machine taken or lost, also of one whose lease ran out by this process's clock
        while the table could not be reached (they are woken at that moment, not at the next round)."""
        loop = asyncio.get_running_loop()
        due = loop.time() + self.lease_time / 3
        while True:
            await asyncio.sleep(max(0.0, min(due, loop.time() + self._until_doubt()) - loop.time()))
            if loop.time() >= due:
                due = loop.time() + self.lease_time / 3
                try:
                    await self.step()
                    if not self.reachable:
                        log.info("%s: the lease table is reachable again", self.holder)
                    self.reachable = True
                except LeaseError as exc:  # the database is away: the leases run out, fence() says None
                    if self.reachable:
                        log.warning("%s: cannot reach the lease table: %s", self.holder, exc)
                    self.reachable = False
            self._tell()

    def _until_doubt(self) -> float:
        """Seconds until fence() stops trusting the oldest renewal of a held machine (lease_time if none)."""
        trusted = self.lease_time - self.margin
        now = self.clock()
        ends = [renewed + trusted - now for m, renewed in self._renewed.items() if m in self._fences]
        # Only doubts still to come: one already past was told at its moment (no wake-ups every 10 ms
        # while the table stays out of reach).
        return min((end for end in ends if end > 0), default=self.lease_time) + 0.01

    def watch(self, machine: str, told: Callable[[bool], None]) -> None:
        """Call `told(True)` when this process may act on `machine` (fence() gives a token), `told(False)`
        when it may no longer; first after entering, then as it changes."""
        self._watchers.setdefault(machine, []).append(told)

    def _tell(self) -> None:
        for machine, watchers in self._watchers.items():
            held = self.fence(machine) is not None
            if self._told.get(machine) != held:
                self._told[machine] = held
                for told in watchers:
                    told(held)

    def fence(self, machine: str) -> Fence | None:
        """The token to act on `machine` with, or None: not held, or held on a renewal too old to trust."""
        fence = self._fences.get(machine)
        renewed = self._renewed.get(machine)
        if fence is None or renewed is None:
            return None
        if self.clock() - renewed > self.lease_time - self.margin:
            return None
        return fence

    def held(self) -> list[str]:
        return sorted(m for m in self._fences if self.fence(m) is not None)
