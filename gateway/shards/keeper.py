"""One shard's leases, kept: join, renew, release what is beyond its share, take what is free.

`LeaseKeeper.step()` is one round, synchronous (the async side runs it in a thread every
renewal interval, a third of the lease time or less, so a lease is renewed twice before it
can expire). What it holds afterwards is `leases`, machine -> Lease; a machine it lost
(renewal refused: it was paused or cut off past its lease) leaves at once, and the caller
must stop acting on it: the fencing token it had is stale from then on.
"""

from __future__ import annotations

from collections.abc import Collection
from dataclasses import dataclass, field

from gateway.errors import StaleFence
from gateway.shards.leases import Lease, LeaseTable
from gateway.shards.planner import plan


@dataclass
class Round:
    """What one step changed."""

    taken: list[str] = field(default_factory=list)
    lost: list[str] = field(default_factory=list)
    released: list[str] = field(default_factory=list)


class LeaseKeeper:
    def __init__(self, table: LeaseTable, holder: str, machines: Collection[str]) -> None:
        self.table = table
        self.holder = holder
        self.machines = sorted(set(machines))
        self.leases: dict[str, Lease] = {}

    def step(self) -> Round:
        done = Round()
        self.table.join(self.holder)
        for machine, lease in list(self.leases.items()):
            try:
                self.leases[machine] = self.table.renew(lease)
            except StaleFence:
                del self.leases[machine]
                done.lost.append(machine)
        wanted = plan(self.holder, self.machines, self.table.members(), self.table.held())
        for machine in wanted.release:
            if machine in self.leases and self.table.release(self.leases.pop(machine)):
                done.released.append(machine)
        for machine in wanted.take:
            taken = self.table.acquire(machine, self.holder)
            if taken is not None:
                self.leases[machine] = taken
                done.taken.append(machine)
        return done

    def stop(self) -> None:
        """A clean stop: every lease released and the membership ended, so others take over at once."""
        for lease in self.leases.values():
            self.table.release(lease)
        self.leases.clear()
        self.table.leave(self.holder)
