"""A static shard: the gateway file's `shard:` says which machines of the fleet this process serves. Pure.

    shard: 2/4                  the second of four shards: every fourth machine in name order, from the second
    shard: [laser-1, press-2]   these machines, by name

Every shard process reads the same fleet (the same mapping files, all checked), and loads only its
machines; with `shard: ${CNC_SHARD}` one gateway file serves every shard (the loader expands the
environment). K/N is balanced within one machine and needs no coordination; leases (leases.py) are
the way that moves machines when a process dies.
"""

from __future__ import annotations

import re
from collections.abc import Sequence
from dataclasses import dataclass

_K_OF_N = re.compile(r"^\s*(\d+)\s*/\s*(\d+)\s*$")
MAX_SHARDS = 1024
LEASE = "lease"  # `shard: lease`: not static; the machines this process holds leases on (holder.py)


@dataclass(frozen=True, slots=True)
class KOfN:
    k: int  # 1-based
    n: int

    def __str__(self) -> str:
        return f"{self.k}/{self.n}"


def parse_k_of_n(text: str) -> KOfN:
    """'2/4' -> KOfN(2, 4); ValueError with what to write otherwise."""
    m = _K_OF_N.match(text)
    if m is None:
        raise ValueError(
            f"{text!r} is no shard: write K/N (2/4: the second of four shards), list the machines by name,"
            " or write lease (the machines this process holds leases on)"
        )
    k, n = int(m.group(1)), int(m.group(2))
    if not 1 <= n <= MAX_SHARDS:
        raise ValueError(f"{text!r}: the number of shards must be between 1 and {MAX_SHARDS}")
    if not 1 <= k <= n:
        raise ValueError(f"{text!r}: the shard must be between 1 and {n} (they count from 1)")
    return KOfN(k, n)


def select(machines: Sequence[str], shard: KOfN | Sequence[str]) -> list[str]:
    """The machines of `shard`, in name order: K/N takes every N-th from the K-th; a list names them."""
    ordered = sorted(set(machines))
    if isinstance(shard, KOfN):
        return [name for index, name in enumerate(ordered) if index % shard.n == shard.k - 1]
    wanted = set(shard)
    return [name for name in ordered if name in wanted]
