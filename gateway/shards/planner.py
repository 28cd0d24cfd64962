"""Which machines each shard should hold: a share of the fleet, balanced within one, moving few.

Pure (no database, no clock): given the fleet's machines, the live members and who holds
what now, `assign` divides the machines among the members and `plan` says what one member
takes and releases to get there. Every member computes the same assignment from the same
table, so they converge without talking to each other: a member over its share releases
the machines it has beyond it, and the others take them once they are free.

Shares: n machines over k members is n // k each, and one more for n % k of them; the extra
ones go to the members that hold the most already (then by name), so a rebalance moves
as few machines as it can. A machine held by a member within its share stays where it is.
"""

from __future__ import annotations

from collections import Counter
from collections.abc import Collection, Mapping
from dataclasses import dataclass


def shares(machines: int, members: Collection[str], held: Mapping[str, str] | None = None) -> dict[str, int]:
    """How many machines each member should hold: balanced within one, the larger shares to the members
    that hold the most now."""
    if not members:
        return {}
    ordered = sorted(set(members))
    base, extra = divmod(machines, len(ordered))
    holding = Counter((held or {}).values())
    larger = sorted(ordered, key=lambda m: (-holding[m], m))[:extra]
    return {m: base + (1 if m in larger else 0) for m in ordered}


def assign(machines: Collection[str], members: Collection[str], held: Mapping[str, str]) -> dict[str, str]:
    """Machine -> the member that should hold it: every machine once, to a live member (none without
    members). `held`: machine -> its holder now (holders that are not members count as nobody)."""
    live = set(members)
    current = {m: h for m, h in held.items() if h in live and m in machines}
    quota = shares(len(set(machines)), live, current)
    result: dict[str, str] = {}
    load: Counter[str] = Counter()
    for machine in sorted(set(machines)):  # keep what members hold, within their shares
        holder = current.get(machine)
        if holder is not None and load[holder] < quota[holder]:
            result[machine] = holder
            load[holder] += 1
    free = iter(m for m in sorted(set(machines)) if m not in result)
    for member in sorted(live):  # the rest to the members short of their share
        while load[member] < quota[member]:
            result[next(free)] = member
            load[member] += 1
    return result


@dataclass(frozen=True, slots=True)
class Plan:
    """What one member does now: take these machines (when free), release these (beyond its share)."""

    take: tuple[str, ...]
    release: tuple[str, ...]
    share: int


def plan(me: str, machines: Collection[str], members: Collection[str], held: Mapping[str, str]) -> Plan:
    live = set(members) | {me}
    target = assign(machines, live, held)
    mine = sorted(m for m, who in target.items() if who == me)
    take = tuple(m for m in mine if held.get(m) != me)
    release = tuple(sorted(m for m, h in held.items() if h == me and target.get(m) != me))
    return Plan(take, release, len(mine))
