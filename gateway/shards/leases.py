"""Leases on machines in PostgreSQL, each with a fencing token: which gateway process serves which machine.

A process (a `holder`, a name unique per process) takes the lease on a machine when
nobody holds it or its holder stopped renewing it for `lease_time`; it renews it while it
serves the machine, and releases it when it stops. Every new holder gets a token from one
sequence, so a machine's tokens grow strictly with each holder. Expiry is decided by the
database's clock (now()), never by the processes' clocks, which can be paused (SIGSTOP, a
VM's migration) or wrong.

A side effect that another shard could also cause (the claim of a job, a write) checks
the token in the same transaction (`check_fence`, which the PostgreSQL job queue calls):
the row is read FOR SHARE, so a takeover waits for that transaction, and a holder that
was paused past its lease finds a newer token, or an expired lease, and is refused.

Members: each process also renews a membership row (`join`), so that the others know how
many share the machines (planner.py divides them).
"""

from __future__ import annotations

import builtins
from dataclasses import dataclass
from typing import Self

from gateway.errors import LeaseError, StaleFence
from gateway.postgres import Database, Transaction
from gateway.shards.fence import Fence

COMPONENT = "shard-leases"
MIGRATIONS = (
    # 1: the leases, one row per machine once anyone took it; the members; one token sequence
    """
    CREATE SEQUENCE shard_tokens;
    CREATE TABLE shard_leases (
        machine TEXT PRIMARY KEY,
        holder TEXT,
        token BIGINT NOT NULL,
        acquired_at TIMESTAMPTZ NOT NULL,
        expires_at TIMESTAMPTZ NOT NULL
    );
    CREATE INDEX shard_leases_holder ON shard_leases (holder);
    CREATE TABLE shard_members (
        holder TEXT PRIMARY KEY,
        joined_at TIMESTAMPTZ NOT NULL,
        expires_at TIMESTAMPTZ NOT NULL
    );
    """,
)


@dataclass(frozen=True, slots=True)
class Lease:
    """A machine's lease as the database has it; `remaining` in seconds by the database's clock (<= 0:
    expired, free for the taking)."""

    machine: str
    holder: str | None
    token: int
    remaining: float

    @property
    def fence(self) -> Fence:
        return Fence(self.machine, self.token)

    @property
    def live(self) -> bool:
        return self.holder is not None and self.remaining > 0


def check_fence(tx: Transaction, fence: Fence) -> None:
    """In the caller's transaction: is `fence` the current, unexpired lease on its machine? StaleFence if
    not. The row stays share-locked until the transaction ends, so no takeover slips in between."""
    row = tx.one(
        "SELECT token, holder, expires_at > now() AS live FROM shard_leases WHERE machine = %s FOR SHARE",
        (fence.machine,),
    )
    if row is None:
        raise StaleFence(f"{fence.machine}: nobody holds its lease, so token {fence.token} is not current")
    if row["token"] != fence.token:
        raise StaleFence(
            f"{fence.machine}: token {fence.token} is stale; {row['holder']} holds {row['token']}"
        )
    if not row["live"] or row["holder"] is None:
        raise StaleFence(f"{fence.machine}: the lease of token {fence.token} has expired")


class LeaseTable:
    """The leases in one database. Open with `with LeaseTable(url) as leases:`; methods are synchronous."""

    def __init__(self, url: str, *, lease_time: float = 10.0) -> None:
        if lease_time <= 0:
            raise ValueError("lease_time must be positive")
        self.db = Database(url, noun="lease table", error=LeaseError)
        self.lease_time = lease_time

    def open(self) -> Self:
        self.db.open()
        self.db.migrate(COMPONENT, MIGRATIONS)
        return self

    def close(self) -> None:
        self.db.close()

    def __enter__(self) -> Self:
        return self.open()

    def __exit__(self, *exc_info: object) -> None:
        self.close()

    # --- one machine --------------------------------------------------------------------------------

    def acquire(self, machine: str, holder: str) -> Lease | None:
        """Take the machine's lease if it is free or expired: a new token, greater than any before. None if
        another holder's lease is still running (or this holder's own: renew that one)."""
        with self.db.transaction() as tx:
            row = tx.one(
                "INSERT INTO shard_leases AS l (machine, holder, token, acquired_at, expires_at)"
                " VALUES (%s, %s, nextval('shard_tokens'), now(), now() + make_interval(secs => %s))"
                " ON CONFLICT (machine) DO UPDATE SET holder = EXCLUDED.holder, token = EXCLUDED.token,"
                " acquired_at = EXCLUDED.acquired_at, expires_at = EXCLUDED.expires_at"
                " WHERE l.holder IS NULL OR l.expires_at <= now()"
                " RETURNING token",
                (machine, holder, self.lease_time),
            )
        return None if row is None else Lease(machine, holder, int(row["token"]), self.lease_time)

    def renew(self, lease: Lease) -> Lease:
        """Extend a lease this holder still has. LeaseError when it expired or another holder took it: the
        machine is lost and its side effects must stop (StaleFence) (a new acquire() gets a new token)."""
        with self.db.transaction() as tx:
            row = tx.one(
                "UPDATE shard_leases SET expires_at = now() + make_interval(secs => %s)"
                " WHERE machine = %s AND holder = %s AND token = %s AND expires_at > now()"
                " RETURNING token",
                (self.lease_time, lease.machine, lease.holder, lease.token),
            )
        if row is None:
            raise StaleFence(f"{lease.machine}: the lease of token {lease.token} is lost (expired or taken)")
        return Lease(lease.machine, lease.holder, lease.token, self.lease_time)

    def release(self, lease: Lease) -> bool:
        """Give a lease up at once (a clean stop, a rebalance), so another takes the machine without waiting
        for it to expire. False if it was no longer this holder's."""
        with self.db.transaction() as tx:
            row = tx.one(
                "UPDATE shard_leases SET holder = NULL, expires_at = now()"
                " WHERE machine = %s AND holder = %s AND token = %s RETURNING token",
                (lease.machine, lease.holder, lease.token),
            )
        return row is not None

    def check(self, fence: Fence) -> None:
        """StaleFence unless `fence` is its machine's current, unexpired lease (on its own transaction; a side
        effect in the database calls check_fence in its own)."""
        with self.db.transaction() as tx:
            check_fence(tx, fence)

    # --- the table ----------------------------------------------------------------------------------

    def leases(self) -> builtins.list[Lease]:
        with self.db.transaction() as tx:
            rows = tx.all(
                "SELECT machine, holder, token, EXTRACT(EPOCH FROM expires_at - now()) AS remaining"
                " FROM shard_leases ORDER BY machine"
            )
        return [Lease(r["machine"], r["holder"], int(r["token"]), float(r["remaining"])) for r in rows]

    def held(self) -> dict[str, str]:
        """Machine -> holder, for the leases running now."""
        return {lease.machine: lease.holder for lease in self.leases() if lease.live and lease.holder}

    # --- members ------------------------------------------------------------------------------------

    def join(self, holder: str) -> None:
        """Say (again) that `holder` is alive and shares the machines, for another lease_time. (Members gone
        for a day are forgotten: every process start is a new holder name.)"""
        with self.db.transaction() as tx:
            tx.execute("DELETE FROM shard_members WHERE expires_at < now() - interval '1 day'")
            tx.execute(
                "INSERT INTO shard_members (holder, joined_at, expires_at)"
                " VALUES (%s, now(), now() + make_interval(secs => %s))"
                " ON CONFLICT (holder) DO UPDATE SET expires_at = EXCLUDED.expires_at",
                (holder, self.lease_time),
            )

    def leave(self, holder: str) -> None:
        with self.db.transaction() as tx:
            tx.execute("DELETE FROM shard_members WHERE holder = %s", (holder,))

    def members(self) -> builtins.list[str]:
        """The holders alive now (by the database's clock), sorted."""
        with self.db.transaction() as tx:
            rows = tx.all("SELECT holder FROM shard_members WHERE expires_at > now() ORDER BY holder")
        return [r["holder"] for r in rows]
